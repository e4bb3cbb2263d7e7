"""Helpers of the bridge tests: an MQTT observer and bridge configs."""
from __future__ import annotations

import json
import os
import threading
from typing import Any, Callable, Dict, List, Optional

import pytest

WAIT = float(os.environ.get("FAP_TEST_WAIT", "20"))   # longest wait for one expected message


def need(what: str, ok: bool) -> None:
    """Skip when ``what`` is missing, but fail under ``CI`` (CI installs it)."""
    if ok:
        return
    if os.environ.get("CI"):
        pytest.fail(f"{what} is missing (CI installs it)")
    pytest.skip(f"{what} is not installed")


class Observer:
    """An MQTT client that records every message on ``topics`` and waits for them."""

    def __init__(self, mqtt: Any, port: int, topics: str = "fap/#", *, client_id: str = "observer",
                 clean: bool = True, tls: Optional[dict] = None, auth: Optional[tuple] = None,
                 v5: bool = False) -> None:
        self.messages: List[Any] = []
        self._cond = threading.Condition()
        self._subscribed = threading.Event()
        if v5:   # MQTT 5: sees the bridge's user properties
            self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5)
        else:
            self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=clean)
        if tls:
            self.c.tls_set(ca_certs=tls["ca"])
        if auth:
            self.c.username_pw_set(*auth)
        self.c.reconnect_delay_set(0.05, 0.5)
        self.c.on_connect = lambda c, u, f, rc, p: c.subscribe(topics, 1)
        self.c.on_subscribe = lambda c, u, mid, rc, p: self._subscribed.set()
        self.c.on_message = self._on_message
        self.c.connect("127.0.0.1", port)
        self.c.loop_start()
        assert self._subscribed.wait(WAIT), "observer could not subscribe"

    def _on_message(self, c: Any, u: Any, m: Any) -> None:
        with self._cond:
            self.messages.append(m)
            self._cond.notify_all()

    def matching(self, topic: str, pred: Callable[[Dict[str, Any]], bool] = lambda d: True) -> List[Any]:
        out = []
        with self._cond:
            for m in self.messages:
                if m.topic == topic:
                    doc = _doc(m.payload)
                    if pred(doc):
                        out.append(doc)
        return out

    def wait_for(self, topic: str, pred: Callable[[Dict[str, Any]], bool] = lambda d: True,
                 count: int = 1, timeout: float = WAIT) -> List[Dict[str, Any]]:
        """The first ``count`` messages on ``topic`` whose JSON satisfies ``pred``."""
        with self._cond:
            ok = self._cond.wait_for(lambda: len(self.matching(topic, pred)) >= count, timeout)
        found = self.matching(topic, pred)
        assert ok, f"{topic}: {len(found)} of {count} messages within {timeout} s; " \
                   f"saw {[m.topic for m in self.messages][-20:]}"
        return found[:count]

    def wait_raw(self, topic: str, payload: bytes, timeout: float = WAIT) -> Any:
        with self._cond:
            ok = self._cond.wait_for(lambda: any(m.topic == topic and m.payload == payload
                                                 for m in self.messages), timeout)
        assert ok, f"{topic}: no {payload!r} within {timeout} s"
        return next(m for m in self.messages if m.topic == topic and m.payload == payload)

    def publish(self, topic: str, doc: Any, timeout: float = WAIT) -> None:
        payload = doc if isinstance(doc, (bytes, str)) else json.dumps(doc)
        self.c.publish(topic, payload, qos=1).wait_for_publish(timeout)

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def _doc(payload: bytes) -> Dict[str, Any]:
    try:
        doc = json.loads(payload)
    except ValueError:
        return {"raw": payload}
    return doc if isinstance(doc, dict) else {"raw": payload}


def bridge_config(port: int, state_dir: str, buses: List[Dict[str, Any]], **broker: Any) -> Any:
    """A checked BridgeConfig for a broker on 127.0.0.1:``port``."""
    from fap_py.bridge.config import from_dict

    url = broker.pop("url", f"mqtt://127.0.0.1:{port}")
    return from_dict({"broker": dict({"url": url, "reconnect_min": 0.05, "reconnect_max": 0.5}, **broker),
                      "bridge": {"host": "test", "state_dir": state_dir, "stats_interval": 0.2},
                      "bus": buses})
