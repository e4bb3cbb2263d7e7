"""The outbox pump works in batches (issue 24: no disk round trip per message): it is not
woken for every PUBACK, only for a batch of them (a quarter of the in-flight window) or
when the window empties; a lone new row goes at once. Driven through paho's callback
with no broker (the link is never started)."""
from __future__ import annotations

from bridge_helpers import bridge_config


def test_the_pump_waits_for_a_batch_of_acknowledgements(tmp_path, paho_mqtt):
    from fap_py.bridge.mqtt import MqttLink
    from fap_py.bridge.store import Store

    cfg = bridge_config(1, str(tmp_path), [{"name": "l", "port": "/dev/null", "protocol": "fap", "slaves": [1]}])
    with Store(str(tmp_path / "s.sqlite")) as store:
        link = MqttLink(cfg, store, lambda *a: None)
        batch = cfg.inflight // 4
        assert link._batch == batch
        store.put_many([("t", b"x", False)] * cfg.inflight)
        link._connected = link._gate_open = True   # connected, the connect's own publications answered
        assert link._ready()                       # new rows and an empty window: at once
        link._inflight = {mid: (mid, "t") for mid in range(1, cfg.inflight + 1)}   # all handed to paho
        link._last_handed = cfg.inflight
        assert not link._ready()                   # nothing acknowledged, nothing new
        for mid in range(1, batch):
            link._on_publish(None, None, mid, None, None)
        assert len(link._acked) == batch - 1 and not link._ready()   # one PUBACK short of a batch
        link._on_publish(None, None, batch, None, None)
        assert link._ready()                       # a batch: one DELETE transaction for all of them
        link._pump_once(0)
        assert link._acked == [] and store.pending == cfg.inflight - batch and link.published == batch
        for mid in range(batch + 1, cfg.inflight + 1):
            link._on_publish(None, None, mid, None, None)
        assert not link._inflight and link._ready()   # the window emptied: the last ones go at once
        link._pump_once(0)
        assert store.pending == 0 and link.published == cfg.inflight


class _Reason:
    """A PUBACK reason as paho gives it."""

    def __init__(self, failure: bool, text: str) -> None:
        self.is_failure = failure
        self.text = text

    def __str__(self) -> str:
        return self.text


def test_probing_gets_past_a_broker_that_drops_the_connection_on_a_row(tmp_path, paho_mqtt):
    """mosquitto 2.0 closes the connection after denying a publication and loses the PUBACKs
    it had queued: without probing, paho re-sends the same rows at every reconnect forever.
    Driven through paho's callbacks with no broker; the paho queue is a stand-in dict."""
    from fap_py.bridge.mqtt import DROPPED_REASON, PROBE_AFTER, PROBE_STRIKES, MqttLink
    from fap_py.bridge.store import Store

    cfg = bridge_config(1, str(tmp_path), [{"name": "l", "port": "/dev/null", "protocol": "fap", "slaves": [1]}])
    with Store(str(tmp_path / "s.sqlite")) as store:
        link = MqttLink(cfg, store, lambda *a: None)
        store.put_many([("t", b"x", False)] * 3)            # seqs 1..3: 2 is the one the broker denies
        link._inflight = {11: (1, "t"), 12: (2, "t"), 13: (3, "t")}
        link._last_handed = 3
        paho_queue = {11: "m", 12: "m", 13: "m", 99: "status"}
        link.client._out_messages = paho_queue              # type: ignore[attr-defined]

        def lose() -> None:
            link._connected = True
            link._on_disconnect(None, None, None, _Reason(True, "Unspecified error"), None)

        def reconnect() -> None:
            flags = type("Flags", (), {"session_present": True})()
            link._on_connect(link.client, None, flags, _Reason(False, "Success"), None)

        for _ in range(PROBE_AFTER - 1):
            lose()
        assert not link.probing and len(link._inflight) == 3   # one loss is an outage, not a verdict
        lose()
        assert link.probing and not link._inflight and link._last_handed == 0
        reconnect()
        assert 99 in paho_queue and not {11, 12, 13} & set(paho_queue)   # paho will not burst them
        assert not link._gate_open and list(link._own.values()) == [link.status_topic]
        for mid in list(link._own):   # status "online" answered: the rows may go
            link._on_publish(None, None, mid, _Reason(False, "Success"), None)
        assert link._gate_open
        assert link._window == 1
        # the pump hands them again one at a time: 1 is acknowledged, 2 kills the connection
        link._inflight = {21: (1, "t")}
        link._on_publish(None, None, 21, _Reason(False, "Success"), None)
        assert link.probing and link._acked == [1]
        link._inflight = {22: (2, "t")}
        for _ in range(PROBE_STRIKES - 1):
            lose()
        assert not link.refused_pubs and link._inflight == {22: (2, "t")}   # still paho's to re-send
        lose()
        assert link.refused_pubs == {DROPPED_REASON: 1} and link._acked == [1, 2]
        assert link.probing                                  # 3 was in flight too: still one by one
        link._inflight = {23: (3, "t")}
        link._on_publish(None, None, 23, _Reason(False, "Success"), None)
        assert not link.probing and link._window == cfg.inflight and link._acked == [1, 2, 3]
        link._pump_once(0)
        assert store.pending == 0 and link.published == 3


def test_a_lost_connection_before_probing_strikes_nothing(tmp_path, paho_mqtt):
    """An ordinary outage (a PUBACK arrives between the losses) never starts probing."""
    from fap_py.bridge.mqtt import PROBE_AFTER, MqttLink
    from fap_py.bridge.store import Store

    cfg = bridge_config(1, str(tmp_path), [{"name": "l", "port": "/dev/null", "protocol": "fap", "slaves": [1]}])
    with Store(str(tmp_path / "s.sqlite")) as store:
        link = MqttLink(cfg, store, lambda *a: None)
        store.put_many([("t", b"x", False)] * (PROBE_AFTER + 1))
        for seq in range(1, PROBE_AFTER + 2):
            link._inflight = {seq: (seq, "t"), 100 + seq: (seq + 100, "t")}
            link._connected = True
            link._on_disconnect(None, None, None, _Reason(True, "Unspecified error"), None)
            link._on_publish(None, None, seq, _Reason(False, "Success"), None)
        assert not link.probing and not link.refused_pubs
