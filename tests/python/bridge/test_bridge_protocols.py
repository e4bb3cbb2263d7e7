"""G485 polling and register writes, exec async and mikroC masters, bridged: each on
the port itself and through ``fap serve`` on it (the bridge one client among others)."""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Iterator

import pytest
from bridge_helpers import WAIT, bridge_config

sys.path.append(str(Path(__file__).resolve().parents[1] / "serve"))  # last: never shadows a conftest
from serve_helpers import mikroc_echo, start_daemon  # the daemon tests' own helpers

VIA = pytest.mark.parametrize("via", ["direct", "daemon"])


@contextlib.contextmanager
def _port(via: str, path: str, tmp_path: Path, protocol: str, *extra: str) -> Iterator[str]:
    """``path`` itself, or the URL of a ``fap serve`` on it."""
    if via == "direct":
        yield path
        return
    d = start_daemon(str(tmp_path), path, *extra, protocol=protocol)
    try:
        yield d.url
    finally:
        d.stop()


@VIA
def test_g485_polling_write_set(broker, observer_factory, tmp_path, via):
    from fap_py.bridge import Bridge
    from fap_py.g485 import SimDevice, Simulator
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus, Simulator(bus.paths[1], [SimDevice(1), SimDevice(2)]) as sim, \
            _port(via, bus.paths[0], tmp_path, "g485", "--timeout", "0.2") as port:
        obs = observer_factory(broker.port)
        buses = [{"name": "g", "port": port, "protocol": "g485", "poll_interval": 0.05,
                  "timeout": 0.2, "device": [{"address": 1, "registers": [[1, 7], [8, 2]]},
                                             {"address": 2, "registers": [[7, 1]]},
                                             {"address": 9, "registers": [[1, 1]]}]}]
        with Bridge(bridge_config(broker.port, str(tmp_path), buses)) as bridge:
            assert bridge.wait_connected(WAIT)
            # polled: registers 1..7 of device 1 (identity 11,1,1,1,1; 6 reads 0; 7 = its ID)
            first = obs.wait_for("fap/g/1/rx", lambda d: d.get("register") == 1)[0]
            assert first["data"] == "0b010101010001" and first["op"] == "read"
            obs.wait_for("fap/g/2/rx", lambda d: d["register"] == 7 and d["data"] == "02")
            obs.wait_for("fap/g/1/state", lambda d: d["state"] == "active")
            # device 9 is absent: inactive, and polling goes on
            obs.wait_for("fap/g/9/state", lambda d: d["state"] == "inactive")
            # write registers 8..9 of device 1; the next polls read them back
            obs.publish("fap/g/1/tx", {"id": "w1", "op": "write", "register": 8, "data": "3210"})
            (ack,) = obs.wait_for("fap/g/1/rx", lambda d: d.get("reply_to") == "w1")
            assert ack["op"] == "write"
            obs.wait_for("fap/g/1/rx", lambda d: d.get("register") == 8 and d["data"] == "3210")
            # an explicit read, a Set command, and a read of a write-only register refused
            obs.publish("fap/g/2/tx", {"id": "r1", "op": "read", "register": 1, "count": 2})
            (reply,) = obs.wait_for("fap/g/2/rx", lambda d: d.get("reply_to") == "r1")
            assert reply["data"] == "0b01"
            obs.publish("fap/g/1/tx", {"id": "s1", "op": "set", "command": "save_eeprom"})
            obs.wait_for("fap/g/1/rx", lambda d: d.get("reply_to") == "s1")
            with sim.device(1).lock:
                assert sim.device(1).eeprom[8:10] == b"\x32\x10"   # saved by the Set
            obs.publish("fap/g/9/tx", {"id": "r9", "op": "read", "register": 1})
            (err,) = obs.wait_for("fap/g/9/error", lambda d: d["id"] == "r9")
            assert "NoResponse" in err["error"]
            obs.publish("fap/g/1/tx", {"id": "x", "op": "explode"})
            obs.wait_for("fap/g/1/error", lambda d: d["id"] == "x" and "op" in d["error"])
            (stats,) = obs.wait_for("fap/g/stats", lambda d: d["bridge"]["poll_errors"] > 0)
            assert stats["engine"]["transactions"] > 0 and stats["engine"]["no_response"] > 0



def test_g485_line_options_reach_the_master(broker, observer_factory, tmp_path):
    """echo_suppression on a bus that does not echo: the C port layer waits
    for an echo that never comes, so every transaction fails with a bus
    collision. That only happens if the bus's line options reach G485Master."""
    from fap_py.bridge import Bridge
    from fap_py.g485 import SimDevice, Simulator
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus, Simulator(bus.paths[1], [SimDevice(1)]):
        obs = observer_factory(broker.port)
        for name, echo in (("plain", False), ("echo", True)):
            buses = [{"name": name, "port": bus.paths[0], "protocol": "g485", "rs485": "none",
                      "rts_polarity": "low", "echo_suppression": echo, "poll_interval": 0.05,
                      "timeout": 0.2, "retries": 0, "device": [{"address": 1, "registers": [[1, 2]]}]}]
            with Bridge(bridge_config(broker.port, str(tmp_path / name), buses)) as bridge:
                assert bridge.wait_connected(WAIT)
                obs.publish(f"fap/{name}/1/tx", {"id": f"r-{name}", "op": "read", "register": 1, "count": 2})
                if echo:
                    (err,) = obs.wait_for(f"fap/{name}/1/error", lambda d: d["id"] == "r-echo")
                    assert "EchoMismatch" in err["error"] and "collision" in err["error"]
                    obs.wait_for(f"fap/{name}/1/state", lambda d: d["state"] == "inactive")
                    (stats,) = obs.wait_for(f"fap/{name}/stats", lambda d: d["bridge"]["poll_errors"] > 0)
                    assert stats["bridge"]["rx"] == 0 and not obs.matching(f"fap/{name}/1/rx")
                else:
                    (m,) = obs.wait_for(f"fap/{name}/1/rx", lambda d: d.get("reply_to") == "r-plain")
                    assert m["data"] == "0b01"
                    obs.wait_for(f"fap/{name}/1/state", lambda d: d["state"] == "active")

@VIA
def test_execasync_master(broker, observer_factory, tmp_path, via):
    from fap_py.bridge import Bridge
    from fap_py.execasync import Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus, Slave(bus.paths[1], node=5, handler=lambda req: b"re:" + req.data).start(), \
            _port(via, bus.paths[0], tmp_path, "exec") as port:
        obs = observer_factory(broker.port)
        buses = [{"name": "ex", "port": port, "protocol": "exec", "nodes": [5],
                  "poll_data": "7071", "poll_interval": 0.05, "timeout": 0.2, "retries": 1}]
        with Bridge(bridge_config(broker.port, str(tmp_path), buses)) as bridge:
            assert bridge.wait_connected(WAIT)
            obs.wait_for("fap/ex/5/rx", lambda d: d["data"] == b"re:pq".hex())
            obs.publish("fap/ex/5/tx", {"id": "e1", "data": "0102"})
            (reply,) = obs.wait_for("fap/ex/5/rx", lambda d: d.get("reply_to") == "e1")
            assert reply["data"] == b"re:\x01\x02".hex()
            obs.publish("fap/ex/6/tx", {"id": "e2", "data": "00"})
            obs.wait_for("fap/ex/6/error", lambda d: d["id"] == "e2")


@VIA
def test_mikroc_master(broker, observer_factory, tmp_path, via):
    from fap_py.bridge import Bridge
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus, mikroc_echo(bus.paths[1]):
        obs = observer_factory(broker.port)
        with _port(via, bus.paths[0], tmp_path, "mikroc", "--baud", "19200", "--timeout", "0.5") as port, \
                Bridge(bridge_config(broker.port, str(tmp_path),
                                     [{"name": "mk", "port": port, "protocol": "mikroc", "baud": 19200,
                                       "timeout": 0.5}])) as bridge:
            assert bridge.wait_connected(WAIT)   # subscribed: a tx now reaches it
            obs.publish("fap/mk/18/tx", {"id": "m1", "data": "010203"})
            (reply,) = obs.wait_for("fap/mk/18/rx", lambda d: d.get("reply_to") == "m1")
            assert reply["data"] == "030201"
            obs.publish("fap/mk/18/tx", {"id": "m2", "data": "0102030405"})   # > 3 bytes: refused
            obs.wait_for("fap/mk/18/error", lambda d: d["id"] == "m2")
