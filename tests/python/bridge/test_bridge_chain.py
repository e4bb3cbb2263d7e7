"""A chain of brokers end to end (issue 37): three mosquitto instances bridged
edge -> site -> core (persistence on), the fap bridge publishing at the edge, a
consumer at the core; a fault proxy between edge and site (drop, delay, half-open,
reset), broker kills and restarts. Every row is accounted for at the core by the
(host, seq) rule; duplicates are counted per hop."""
from __future__ import annotations

import contextlib
import time

import pytest
from bridge_helpers import WAIT, need
from fault_proxy import FaultProxy, wait_until
from fleet_helpers import accounting, fleet_config, rx_rows
from mosquitto import MOSQUITTO, Mosquitto


def bridge_lines(name: str, port: int) -> list:
    """A mosquitto bridge section: fap/# out at QoS 1, a persistent session, quick retries."""
    return [f"connection {name}", f"address 127.0.0.1:{port}", "topic fap/# out 1",
            "cleansession false", f"remote_clientid {name}", "keepalive_interval 5",
            "restart_timeout 1", "bridge_protocol_version mqttv311", "notifications false"]


@contextlib.contextmanager
def chain(tmp_path):
    """core <- site <- proxy <- edge, each a mosquitto with persistence."""
    core = Mosquitto(str(tmp_path / "core"))
    site = Mosquitto(str(tmp_path / "site"), extra=bridge_lines("site-core", core.port))
    with core, site, FaultProxy(site.port) as proxy:
        edge = Mosquitto(str(tmp_path / "edge"), extra=bridge_lines("edge-site", proxy.port))
        with edge:
            yield edge, proxy, site, core


@pytest.fixture
def brokers(tmp_path, paho_mqtt):
    need("mosquitto", MOSQUITTO is not None)
    with chain(tmp_path) as c:
        yield c


def test_a_chain_edge_site_core_with_faults_loses_nothing(brokers, observer_factory, tmp_path):
    from fap_py.bridge import Bridge

    edge, proxy, site, core = brokers
    consumer = observer_factory(core.port, "fap/line1/#", client_id="core-consumer", clean=False)
    at_site = observer_factory(site.port, "fap/line1/#", client_id="site-watch", clean=False)
    at_edge = observer_factory(edge.port, "fap/line1/#", client_id="edge-watch", clean=False)
    sent = 0

    def burst(bridge, n=100):
        nonlocal sent
        rx_rows(bridge, sent, n)
        sent += n

    def at_core():
        return accounting(consumer.messages)["data"] == set(range(sent))

    phases = {}
    with Bridge(fleet_config([edge.port], str(tmp_path / "state"))) as bridge:
        assert bridge.wait_connected(WAIT)
        t = time.monotonic()
        burst(bridge)
        assert wait_until(at_core, WAIT), "through the chain"
        phases["clear"] = time.monotonic() - t
        for fault in ("drop", "half_open"):      # a partition in the middle, then a reset heals it
            proxy.set(fault)
            t = time.monotonic()
            burst(bridge)
            assert wait_until(lambda: accounting(at_edge.messages)["data"] == set(range(sent)), WAIT)
            assert not at_core()                 # held: the partition is real
            proxy.set("reset")
            assert wait_until(lambda: proxy.counters["resets"] + proxy.counters["refused"] > 0, WAIT)
            proxy.set("pass")
            assert wait_until(at_core, WAIT), f"after {fault}"
            phases[fault] = time.monotonic() - t
        proxy.set("delay", 0.05)                 # a slow link: late, never lost
        t = time.monotonic()
        burst(bridge)
        assert wait_until(at_core, WAIT), "delay"
        phases["delay"] = time.monotonic() - t
        proxy.set("pass")
        site.stop()                              # the middle broker killed and restarted
        t = time.monotonic()
        burst(bridge)
        site.start()
        assert wait_until(at_core, WAIT), "site restart"
        phases["site restart"] = time.monotonic() - t
        edge.stop()                              # the bridge's own broker: the outbox holds
        t = time.monotonic()
        burst(bridge)
        assert bridge.store.pending >= 100
        edge.start()
        assert wait_until(at_core, WAIT), "edge restart"
        phases["edge restart"] = time.monotonic() - t
        assert bridge.link.drain(WAIT)
    hops = {name: accounting(o.messages) for name, o in (("edge", at_edge), ("site", at_site),
                                                          ("core", consumer))}
    got = hops["core"]
    assert got["data"] == set(range(sent)) and sent == 600   # every row at the core, once by (host, seq)
    assert bridge.not_stored == 0 and bridge.store.dropped == 0 and bridge.link.refused_total == 0
    print("chain phases (s):", {k: round(v, 2) for k, v in phases.items()},
          "duplicates per hop:", {k: v["duplicates"] for k, v in hops.items()},
          "in order:", {k: v["in_order"] for k, v in hops.items()}, "proxy:", proxy.counters)
