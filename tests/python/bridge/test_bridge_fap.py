"""A FAP master and slaves on the virtual bus, bridged to a real mosquitto."""
from __future__ import annotations

import pytest
from bridge_helpers import WAIT, bridge_config


@pytest.fixture
def fap_bus():
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(3) as bus:
        s1, s2 = Slave(bus.paths[1], id=1), Slave(bus.paths[2], id=2)
        try:
            yield bus, s1, s2
        finally:
            s1.close()
            s2.close()


def _master_bus(bus):
    return [{"name": "line1", "port": bus.paths[0], "protocol": "fap", "role": "master",
             "slaves": [1, 2], "id_cycle": 0.1}]


def test_messages_both_ways_state_and_status(broker, observer_factory, fap_bus, tmp_path):
    from fap_py.bridge import Bridge

    bus, s1, s2 = fap_bus
    obs = observer_factory(broker.port)
    cfg = bridge_config(broker.port, str(tmp_path / "state"), _master_bus(bus))
    with Bridge(cfg) as bridge:
        assert bridge.wait_connected(WAIT)
        obs.wait_raw("fap/bridge/test/status", b"online")
        # bus -> broker: each slave's message on its own rx topic, data as hex, with seq and ts
        s1.send(b"hello")
        s2.send(b"\x01\x02\x03")
        (m1,) = obs.wait_for("fap/line1/1/rx")
        (m2,) = obs.wait_for("fap/line1/2/rx")
        assert (m1["data"], m1["node"], m1["bus"]) == ("68656c6c6f", 1, "line1")
        assert m2["data"] == "010203"
        assert m1["ts"].endswith("Z") and m1["host"] == "test" and m2["seq"] > 0
        # broker -> bus: a tx reaches the slave once, even when delivered twice with the same id
        obs.publish("fap/line1/2/tx", {"id": "t-1", "data": "cafe"})
        obs.publish("fap/line1/2/tx", {"id": "t-1", "data": "cafe"})
        obs.publish("fap/line1/2/tx", {"id": "t-2", "data": "beef"})
        assert s2.recv(WAIT).data == b"\xca\xfe"
        assert s2.recv(WAIT).data == b"\xbe\xef"   # t-1 was not executed a second time
        assert s2.rx_pending == 0
        obs.wait_for("fap/line1/stats", lambda d: d["tx_duplicates"] >= 1 and d["bridge"]["tx"] == 2)
        # a tx that cannot be carried out: an error with its id
        obs.publish("fap/line1/1/tx", {"id": "bad", "data": "zz"})
        (err,) = obs.wait_for("fap/line1/1/error")
        assert err["id"] == "bad" and "hex" in err["error"]
        obs.publish("fap/line1/1/tx", {"data": "00"})
        obs.wait_for("fap/line1/1/error", lambda d: d["id"] is None and "id" in d["error"])
        # a node number no FAP bus has (nor any bus: > 255): refused on its own error topic
        obs.publish("fap/line1/99999/tx", {"id": "far", "data": "00"})
        (far,) = obs.wait_for("fap/line1/99999/error")
        assert far["node"] == 99999 and "outside" in far["error"]
        # retained state: a late subscriber gets every slave's state at once
        late = observer_factory(broker.port, "fap/line1/+/state", client_id="late")
        s1_state = late.wait_for("fap/line1/1/state", lambda d: d["state"] == "active")[0]
        late.wait_for("fap/line1/2/state", lambda d: d["state"] == "active")
        assert s1_state["last_seen"].endswith("Z")
        assert all(m.retain for m in late.messages[:2])
    # a clean stop leaves "offline" retained
    obs.wait_raw("fap/bridge/test/status", b"offline")
    later = observer_factory(broker.port, "fap/bridge/+/status", client_id="later")
    msg = later.wait_raw("fap/bridge/test/status", b"offline")
    assert msg.retain


def test_slave_becomes_inactive(broker, observer_factory, tmp_path):
    from fap_py.bridge import Bridge
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(3) as bus:
        obs = observer_factory(broker.port)
        buses = [{"name": "line1", "port": bus.paths[0], "protocol": "fap", "slaves": [1],
                  "id_cycle": 0.1, "data_done_timeout": 0.2}]
        s1 = Slave(bus.paths[1], id=1)
        with Bridge(bridge_config(broker.port, str(tmp_path), buses)):
            obs.wait_for("fap/line1/1/state", lambda d: d["state"] == "active")
            s1.close()       # the slave goes away: the master marks it inactive
            obs.wait_for("fap/line1/1/state", lambda d: d["state"] == "inactive" and d["last_seen"])


def test_bridge_as_fap_slave(broker, observer_factory, tmp_path):
    from fap_py.bridge import Bridge
    from fap_py.fap import Master
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus:
        obs = observer_factory(broker.port)
        buses = [{"name": "cell", "port": bus.paths[1], "protocol": "fap", "role": "slave", "id": 7}]
        with Master(bus.paths[0], slaves=[7], id_cycle=0.1) as master, \
                Bridge(bridge_config(broker.port, str(tmp_path), buses)) as bridge:
            assert bridge.wait_connected(WAIT)
            master.wait_active([7], timeout=WAIT)
            master.send(b"\x10\x20", to=7)
            (m,) = obs.wait_for("fap/cell/0/rx")
            assert m["data"] == "1020" and m["node"] == 0
            obs.wait_for("fap/cell/0/state", lambda d: d["state"] == "active")
            obs.publish("fap/cell/0/tx", {"id": 42, "data": "abcd"})
            assert master.recv(WAIT) .data == b"\xab\xcd"
