"""Sparkplug 3.0 primary host (issue 37): births wait for the host's STATE online, data
is held meanwhile and follows the births in order with a continuous seq; a STATE
offline ends the session (NDEATH); hostile STATE payloads are refused and counted.
Decoded with the Eclipse Tahu schema (independent of the bridge's encoder)."""
from __future__ import annotations

import json

from bridge_helpers import WAIT
from fault_proxy import wait_until
from fleet_helpers import fleet_config, rx_rows
from test_bridge_sparkplug import _tahu

STATE = "spBv1.0/STATE/scada"
BASE = "spBv1.0/plant"


def _sp_config(port, state_dir):
    cfg = fleet_config([port], state_dir, host="edge1",
                       sparkplug={"group_id": "plant", "primary_host_id": "scada"})
    import dataclasses

    bus = dataclasses.replace(cfg.buses[0], sparkplug=True)
    return dataclasses.replace(cfg, buses=(bus,))


def test_primary_host_offline_hold_online_births_then_data(broker, observer_factory, tmp_path):
    pb = _tahu()
    from fap_py.bridge import Bridge

    obs = observer_factory(broker.port, "spBv1.0/#", client_id="sp-obs")
    host = observer_factory(broker.port, "nothing/#", client_id="scada-host")

    def edge_msgs():
        with obs._cond:
            return [(m.topic.split("/")[2], pb.Payload.FromString(m.payload)) for m in obs.messages
                    if m.topic.startswith(f"{BASE}/") and "/edge1" in m.topic]

    def kinds():
        return [k for k, _ in edge_msgs()]

    def state(doc, retain=True):
        payload = doc if isinstance(doc, bytes) else json.dumps(doc).encode()
        host.c.publish(STATE, payload, qos=1, retain=retain).wait_for_publish(WAIT)

    with Bridge(_sp_config(broker.port, str(tmp_path / "state"))) as bridge:
        node = bridge.output("sparkplug").node
        assert bridge.wait_connected(WAIT)
        assert wait_until(lambda: node._session, WAIT)
        rx_rows(bridge, 0, 5)                                  # held: the host has said nothing yet
        assert wait_until(lambda: len(node._queue) == 5, WAIT)
        # hostile STATE payloads: refused, counted, never acted on
        for bad in (b"not json", b"\xff\xfe", [1], {"online": "yes", "timestamp": 1}, {"online": True},
                    {"online": True, "timestamp": True}, {"online": True, "timestamp": -5},
                    {"online": True, "timestamp": 1.5}, b"{" * 3000):
            state(bad if isinstance(bad, bytes) else bad, retain=False)
        assert wait_until(lambda: sum(node.state_refused.values()) == 9, WAIT), node.state_refused
        assert not node.connected and "NBIRTH" not in kinds()   # tck-id-...-phid-wait
        assert set(node.state_refused) >= {"not JSON", "not a JSON object", "online is not a boolean",
                                           "timestamp is not an integer of ms since the epoch"}
        state({"online": True, "timestamp": 1000})               # online: births, then the held data
        assert wait_until(lambda: node.connected and len(data_of(edge_msgs())) == 5, WAIT), kinds()
        seq = [p.seq for _, p in edge_msgs()]
        assert kinds()[0] == "NBIRTH" and kinds()[1] == "DBIRTH" and seq == list(range(len(seq)))
        assert data_of(edge_msgs()) == [bytes.fromhex(f"{i:06x}") for i in range(5)]
        bd0 = [m.long_value for m in edge_msgs()[0][1].metrics if m.name == "bdSeq"][0]

        state({"online": False, "timestamp": 500})               # older than the last: refused
        assert wait_until(lambda: node.state_refused.get("timestamp older than the last STATE taken") == 1, WAIT)
        assert node.connected and "NDEATH" not in kinds()

        state({"online": False, "timestamp": 2000})              # offline: NDEATH, a new session waits
        assert wait_until(lambda: "NDEATH" in kinds(), WAIT)
        death = [p for k, p in edge_msgs() if k == "NDEATH"][0]
        assert [m.long_value for m in death.metrics if m.name == "bdSeq"] == [bd0] and not death.HasField("seq")
        assert wait_until(lambda: node._session and not node.connected, WAIT)
        n_before = len(edge_msgs())
        rx_rows(bridge, 5, 3)
        assert wait_until(lambda: len(node._queue) == 3, WAIT)
        assert len(edge_msgs()) == n_before                      # held, not sent
        state({"online": True, "timestamp": 3000})
        assert wait_until(lambda: len(data_of(edge_msgs()[n_before:])) == 3, WAIT), kinds()
        after = edge_msgs()[n_before:]
        assert [k for k, _ in after][:2] == ["NBIRTH", "DBIRTH"]
        assert [p.seq for _, p in after] == list(range(len(after)))   # continuous from the NBIRTH
        assert data_of(after) == [bytes.fromhex(f"{i:06x}") for i in range(5, 8)]
        assert all(m.is_historical for _, p in after if _ == "DDATA" for m in p.metrics if m.name == "data")
        bd1 = [m.long_value for m in after[0][1].metrics if m.name == "bdSeq"][0]
        assert bd1 == (bd0 + 1) % 256 and node.host_offline == 1
        assert node.queue_dropped == 0
    host.c.publish(STATE, b"", qos=1, retain=True).wait_for_publish(WAIT)   # the retained STATE cleared


def data_of(msgs):
    """The data bytes of the DDATA messages, in order."""
    out = []
    for k, p in msgs:
        if k == "DDATA":
            out += [m.bytes_value for m in p.metrics if m.name == "data"]
    return out
