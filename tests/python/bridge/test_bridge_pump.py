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
        link._connected = True
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
