"""``[metrics] sim_control``: the counters of a ``fap sim`` beside the bridge join its
Prometheus metrics, read from the sim's control socket at scrape time (docs/bridge.md)."""
from __future__ import annotations

import urllib.request
from typing import Dict, Tuple

import pytest
from bridge_helpers import WAIT

Samples = Dict[Tuple[str, Tuple[Tuple[str, str], ...]], float]


def _scrape(port: int) -> Samples:
    from prometheus_client.parser import text_string_to_metric_families

    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=WAIT) as r:
        text = r.read().decode()
    return {(s.name, tuple(sorted(s.labels.items()))): s.value
            for fam in text_string_to_metric_families(text) for s in fam.samples}


def _node(samples: Samples, name: str, address: int, **extra: str) -> float:
    labels = {"bus": "field", "protocol": "g485", "address": str(address), **extra}
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def test_sim_counters_join_the_bridge_metrics(broker, observer_factory, tmp_path) -> None:
    pytest.importorskip("prometheus_client")
    from fap_py.bridge import Bridge
    from fap_py.bridge.config import from_dict
    from fap_py.sim import Sim
    from fap_py.sim._control import ControlServer
    from fap_py.vbus import VirtualBus

    spec = f"unix:{tmp_path}/sim.sock"
    site = {"bus": [{"name": "field", "protocol": "g485", "port": "", "node": [{"address": 1}, {"address": 2}]}]}
    with VirtualBus(2) as vbus:
        site["bus"][0]["port"] = vbus.paths[1]
        with Sim(site) as sim, ControlServer(sim, spec) as control:
            sim.add_fault("no_reply", node=2)
            cfg = from_dict({
                "broker": {"url": f"mqtt://127.0.0.1:{broker.port}", "reconnect_min": 0.05},
                "bridge": {"host": "test", "state_dir": str(tmp_path / "state"), "stats_interval": 0.2},
                "metrics": {"listen": "127.0.0.1:0", "sim_control": spec},
                "bus": [{"name": "g", "port": vbus.paths[0], "protocol": "g485", "poll_interval": 0.02,
                         "timeout": 0.05, "retries": 0,
                         "device": [{"address": 1, "registers": [[7, 1]]}, {"address": 2, "registers": [[7, 1]]}]}]})
            obs = observer_factory(broker.port)
            with Bridge(cfg) as bridge:
                assert bridge.wait_connected(WAIT)
                port = bridge.output("metrics").port
                # both sides have counted: the bridge found node 2 silent (the sim's no_reply
                # fault) and polled node 1; the sim served them
                obs.wait_for("fap/g/2/state", lambda d: d["state"] == "inactive")
                obs.wait_for("fap/g/1/rx", lambda d: d.get("register") == 7)
                assert sim.wait_for(lambda st: st["buses"][0]["nodes"][0]["replies"] >= 1, WAIT)
                got = _scrape(port)
                after = sim.status()
                assert got[("fap_sim_up", ())] == 1.0
                assert got[("fap_bridge_node_timeouts_total", (("bus", "g"), ("node", "2")))] > 0
                served = {n["address"]: n for n in after["buses"][0]["nodes"]}
                # scraped before `after` was read: never more than it, and counted
                assert 0 < _node(got, "fap_sim_node_requests_total", 1) <= served[1]["requests"]
                assert 0 < _node(got, "fap_sim_node_replies_total", 1) <= served[1]["replies"]
                assert _node(got, "fap_sim_node_replies_total", 2) == 0
                assert 0 < _node(got, "fap_sim_node_faults_total", 2, kind="no_reply") \
                    <= served[2]["faults"]["no_reply"]
                assert 0 < got[("fap_sim_faults_applied_total", (("kind", "no_reply"),))] \
                    <= after["faults_applied"]["no_reply"]
                assert got[("fap_sim_faults_active", ())] == 1.0
                assert got[("fap_sim_bus_reopened_total", (("bus", "field"), ("protocol", "g485")))] == 0
                assert ("fap_bridge_bus_up", (("bus", "g"), ("protocol", "g485"))) in got
                control.close()                      # the sim no longer answers: up 0, no counters
                gone = _scrape(port)
                assert gone[("fap_sim_up", ())] == 0.0
                assert not any(name.startswith("fap_sim_node") for name, _ in gone)
                assert ("fap_bridge_bus_up", (("bus", "g"), ("protocol", "g485"))) in gone


@pytest.mark.parametrize("metrics,message", [
    ({"sim_control": "unix:/tmp/x.sock"}, "metrics.sim_control needs metrics.listen"),
    ({"listen": "127.0.0.1:0", "sim_control": "/tmp/x.sock"}, "--control takes unix:PATH"),
    ({"listen": "127.0.0.1:0", "sim_control": 5}, "sim_control"),
])
def test_sim_control_config_is_checked(tmp_path, metrics, message) -> None:
    from fap_py.bridge.config import from_dict
    from fap_py.errors import FapError

    with pytest.raises(FapError, match=message):
        from_dict({"broker": {"url": "mqtt://127.0.0.1:1883"},
                   "bridge": {"host": "test", "state_dir": str(tmp_path)}, "metrics": metrics,
                   "bus": [{"name": "g", "port": "/dev/null", "protocol": "g485",
                            "device": [{"address": 1, "registers": [[7, 1]]}]}]})
