"""``fap web --mqtt BRIDGE_CONFIG``: a bus as a bridge publishes it (docs/bridge.md, "Topics").

Not wire frames: the bridge's ``rx``, ``state`` and ``error`` publications of one bus are
the page's messages (``{"event": "rx"|"state"|"error"|"stats", "topic", "bus", "node",
"ts", "payload"}``), and its ``stats`` publication's per-node counters are the node table
(the bridge's engine counts them). Subscribes read-only: nothing is published.
"""
from __future__ import annotations

import datetime
import json
import logging
import threading
from typing import Any, Dict, List, Optional

from .._validate import check_path
from ..errors import InvalidTypeError, InvalidValueError
from ._hub import Hub
from ._sources import Source

log = logging.getLogger("fap_py.web")

#: the largest publication taken (the bridge's are a few hundred bytes)
MAX_PAYLOAD = 256 * 1024


def _ts(text: Any) -> Optional[float]:
    """An RFC 3339 ``ts`` / ``last_seen`` as epoch seconds (None when absent or bad)."""
    if not isinstance(text, str):
        return None
    try:
        return datetime.datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp()
    except ValueError:
        return None


class MqttSource(Source):
    """One bus of a bridge (its config file: the broker, the prefix, the bus names), as the
    broker carries it."""

    kind = "mqtt"

    def __init__(self, config: str, bus: Optional[str] = None) -> None:
        from ..bridge.config import load

        super().__init__("auto", 0)
        self.config_path = check_path(config, "config")
        if bus is not None and not isinstance(bus, str):
            raise InvalidTypeError(f"bus must be a bus name (str), not {type(bus).__name__}")
        self.cfg = load(self.config_path)
        names = [b.name for b in self.cfg.buses]
        if bus is not None and bus not in names:
            raise InvalidValueError(f"bus must be one of {', '.join(names)}, not {bus!r}")
        self.bus = bus or names[0]
        b = self.cfg.buses[names.index(self.bus)]
        self.protocol = b.protocol
        self.baud = getattr(b, "baud", 0) or 0
        self.base = f"{self.cfg.prefix}/{self.bus}"
        self.connected = threading.Event()
        self.refused = 0                 # publications not taken (too large, not JSON): counted
        self._client: Any = None
        self._states: Dict[str, Dict[str, Any]] = {}

    def describe(self) -> Dict[str, Any]:
        br = self.cfg.broker
        return {**super().describe(), "bus": self.bus, "broker": f"{br.host}:{br.port}",
                "topics": f"{self.base}/#", "connected": self.connected.is_set(), "refused": self.refused}

    def open(self) -> None:
        from ..bridge.mqtt import paho

        mqtt = paho()
        br = self.cfg.broker
        version = mqtt.MQTTv5 if br.protocol == "5" else mqtt.MQTTv311
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"fap-web-{id(self):x}", protocol=version)
        if br.username is not None:
            c.username_pw_set(br.username, br.password)
        if br.tls:
            c.tls_set(ca_certs=br.ca, certfile=br.cert, keyfile=br.key)
        c.on_connect = self._on_connect
        c.on_message = self._on_message
        c.reconnect_delay_set(br.reconnect_min, br.reconnect_max)
        self._client = c
        self._hub: Optional[Hub] = None
        c.connect_async(br.host, br.port, br.keepalive)

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any = None) -> None:
        if getattr(reason, "is_failure", False):
            log.error("mqtt: the broker refused us: %s", reason)
            return
        client.subscribe([(f"{self.base}/+/rx", 0), (f"{self.base}/+/state", 0), (f"{self.base}/+/error", 0),
                          (f"{self.base}/stats", 0)])
        self.connected.set()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        hub = self._hub
        if hub is None:
            return
        try:
            if len(msg.payload) > MAX_PAYLOAD:
                raise ValueError("too large")
            payload = json.loads(msg.payload)
            if not isinstance(payload, dict):
                raise ValueError("not an object")
        except (ValueError, UnicodeDecodeError, RecursionError):
            self.refused += 1
            return
        level = msg.topic[len(self.base) + 1:].split("/")
        kind = level[-1]
        node = level[0] if len(level) == 2 else None
        t = _ts(payload.get("ts"))
        obj = {"event": kind, "protocol": "mqtt", "topic": msg.topic, "bus": self.bus, "node": node, "t": t,
               "port": None, "ts": payload.get("ts"), "ok": kind != "error",
               "error": payload.get("error") if kind == "error" else None, "payload": payload}
        role = {"rx": "ans", "error": "err"}.get(kind)
        if kind == "state" and node is not None:
            self._states[node] = payload
        if kind == "stats":
            hub.set_nodes(self._rows(payload))
        hub.publish_messages([(obj, node, role, t)])

    def _rows(self, stats: Dict[str, Any]) -> List[Dict[str, Any]]:
        """The node table from a stats publication's ``nodes`` and the nodes' states."""
        rows: List[Dict[str, Any]] = []
        found = stats.get("nodes")
        nodes: Dict[str, Any] = found if isinstance(found, dict) else {}
        for name in sorted(nodes, key=lambda k: int(k) if str(k).isdigit() else 0):
            n = nodes[name] if isinstance(nodes[name], dict) else {}
            st = self._states.get(str(name), {})
            last = _ts(st.get("last_seen"))
            num = {k: n[k] if isinstance(n.get(k), (int, float)) and not isinstance(n.get(k), bool) else 0
                   for k in ("rx", "tx", "replies", "timeouts", "errors")}
            rows.append({"node": str(name), "frames": num["rx"] + num["tx"],
                         # the bridge counts answers and timeouts, not polls sent: a poll is one of them
                         "requests": max(num["tx"], num["replies"] + num["timeouts"]),
                         "replies": num["replies"], "timeouts": num["timeouts"], "errors": num["errors"],
                         "errors_by_kind": {}, "collisions": 0, "last_seen": last,
                         "reply_p50_ms": n.get("reply_ms") if isinstance(n.get("reply_ms"), (int, float)) else None,
                         "reply_p99_ms": None,
                         "active": None if not st else st.get("state") == "active",
                         "live": st.get("state") == "active"})
        return rows

    def run(self, hub: Hub, stop: threading.Event) -> None:
        self._check_run(hub, stop)
        if self._client is None:
            raise InvalidValueError("MqttSource.run before open()")
        self._hub = hub
        self._client.loop_start()
        try:
            stop.wait()
        finally:
            self._client.disconnect()
            self._client.loop_stop()

    def close(self) -> None:
        self._client = None


__all__ = ["MqttSource"]
