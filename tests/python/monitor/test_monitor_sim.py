"""``fap monitor --sim-control unix:PATH``: the counters of the sim on the bus follow the
monitor's summary (docs/monitor.md)."""
from __future__ import annotations

import json

from fap_py.cli import main
from fap_py.g485 import G485Master, NoResponseError


def test_monitor_prints_the_sims_counters(tmp_path, capsys) -> None:
    from fap_py.sim import Sim
    from fap_py.sim._control import ControlServer
    from fap_py.vbus import VirtualBus

    spec = f"unix:{tmp_path}/sim.sock"
    cap = str(tmp_path / "bus.cap")
    bus = VirtualBus(2, capture=cap)
    site = {"bus": [{"name": "field", "protocol": "g485", "port": bus.paths[1],
                     "node": [{"address": 1}, {"address": 2}]}]}
    with Sim(site) as sim, ControlServer(sim, spec):
        with bus, G485Master(bus.paths[0], timeout=0.05, retries=0, wake_up=False) as master:
            for _ in range(3):
                assert master.read(1, 7) == b"\x01"
            sim.add_fault("no_reply", node=2)
            try:
                master.read(2, 7)
                raise AssertionError("node 2 answered through its no_reply fault")
            except NoResponseError:
                pass
            assert sim.wait_for(lambda st: st["faults_applied"].get("no_reply") == 1)
        st = sim.status()       # no traffic from here on: the counters the monitor must show
        n1 = st["buses"][0]["nodes"][0]
        assert n1["address"] == 1 and n1["replies"] >= 3
        # the bus is closed (its capture written); the sim still answers on its socket
        assert main(["monitor", "--protocol", "g485", "--capture", cap, "--json", "-q",
                     "--sim-control", spec]) == 0
        lines = capsys.readouterr().out.splitlines()
        last = json.loads(lines[-1])
        assert last["event"] == "sim" and last["control"] == spec
        assert last["requests"] == st["requests"] and last["faults_applied"]["no_reply"] == 1
        assert last["buses"] == st["buses"]
        assert last["buses"][0]["nodes"][1]["faults"] == {"no_reply": 1}
        assert main(["monitor", "--protocol", "g485", "--capture", cap, "--stats", "-q",
                     "--sim-control", spec]) == 0
        out = capsys.readouterr().out
        assert f"sim ({spec}): {st['requests']} requests served, faults applied: no_reply 1" in out
        assert f"  node 1: {n1['requests']} requests, {n1['replies']} replies\n" in out
        assert "  node 2: 1 requests, 0 replies, faults no_reply 1\n" in out


def test_monitor_refuses_a_sim_that_does_not_answer(tmp_path, capsys) -> None:
    cap = tmp_path / "empty.cap"
    assert main(["monitor", "--protocol", "g485", "--raw", str(cap), "--sim-control",
                 f"unix:{tmp_path}/none.sock"]) == 3
    err = capsys.readouterr().err
    assert "control socket" in err and "is `fap sim" in err
    assert main(["monitor", "--raw", str(cap), "--sim-control", "tcp:1"]) == 2
    assert "unix:PATH" in capsys.readouterr().err
