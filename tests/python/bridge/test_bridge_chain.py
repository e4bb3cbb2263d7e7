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


def bridge_lines(name: str, port: int, topics=("fap/# out 1",)) -> list:
    """A mosquitto bridge section: fap/# out at QoS 1, a persistent session, quick retries."""
    return [f"connection {name}", f"address 127.0.0.1:{port}", *(f"topic {t}" for t in topics),
            "cleansession false", f"remote_clientid {name}", "keepalive_interval 5",
            "restart_timeout 1", "bridge_protocol_version mqttv311", "notifications false"]


@contextlib.contextmanager
def chain(tmp_path, topics=("fap/# out 1",)):
    """core <- site <- proxy <- edge, each a mosquitto with persistence."""
    core = Mosquitto(str(tmp_path / "core"))
    site = Mosquitto(str(tmp_path / "site"), extra=bridge_lines("site-core", core.port, topics))
    with core, site, FaultProxy(site.port) as proxy:
        edge = Mosquitto(str(tmp_path / "edge"), extra=bridge_lines("edge-site", proxy.port, topics))
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


def test_a_primary_host_at_the_core_offline_and_back(paho_mqtt, observer_factory, tmp_path):
    """The Sparkplug primary host sits at the core; its STATE reaches the edge through the
    chain (spBv1.0/# both ways): births only once it is online, data held while it is
    offline, then births and the held data in order at the core."""
    import dataclasses
    import json

    from test_bridge_sparkplug import _tahu

    from fap_py.bridge import Bridge

    need("mosquitto", MOSQUITTO is not None)
    pb = _tahu()
    with chain(tmp_path, ("fap/# out 1", "spBv1.0/# both 1")) as (edge, proxy, site, core):
        scada = observer_factory(core.port, "spBv1.0/plant/#", client_id="scada")

        def state(online, ts):
            scada.c.publish("spBv1.0/STATE/scada", json.dumps({"online": online, "timestamp": ts}), qos=1,
                            retain=True).wait_for_publish(WAIT)

        def at_core():
            with scada._cond:
                return [(m.topic.split("/")[2], pb.Payload.FromString(m.payload)) for m in scada.messages
                        if "/edge1" in m.topic]

        def ddata(msgs):
            return [m.bytes_value for k, p in msgs if k == "DDATA" for m in p.metrics if m.name == "data"]

        cfg = fleet_config([edge.port], str(tmp_path / "state"), host="edge1",
                           sparkplug={"group_id": "plant", "primary_host_id": "scada"})
        cfg = dataclasses.replace(cfg, buses=(dataclasses.replace(cfg.buses[0], sparkplug=True),))
        state(True, 1000)                        # retained at the core before the edge node starts
        with Bridge(cfg) as bridge:
            node = bridge.output("sparkplug").node
            assert bridge.wait_connected(WAIT)
            assert wait_until(lambda: [k for k, _ in at_core()][:1] == ["NBIRTH"], WAIT), "births via the chain"
            rx_rows(bridge, 0, 5)
            assert wait_until(lambda: len(ddata(at_core())) == 5, WAIT)
            state(False, 2000)                   # the host goes offline: NDEATH reaches the core
            assert wait_until(lambda: "NDEATH" in [k for k, _ in at_core()], WAIT)
            assert wait_until(lambda: node._session and not node.connected, WAIT)
            n = len(at_core())
            rx_rows(bridge, 5, 5)                # held at the edge node
            assert wait_until(lambda: len(node._queue) == 5, WAIT)
            state(True, 3000)                    # back: births, then the held data, in order
            assert wait_until(lambda: len(ddata(at_core()[n:])) == 5, WAIT)
            after = at_core()[n:]
            assert [k for k, _ in after][:2] == ["NBIRTH", "DBIRTH"]
            assert [p.seq for _, p in after] == list(range(len(after)))
            assert ddata(after) == [bytes.fromhex(f"{i:06x}") for i in range(5, 10)]
            assert sum(node.state_refused.values()) == 0 and node.queue_dropped == 0
        scada.c.publish("spBv1.0/STATE/scada", b"", qos=1, retain=True).wait_for_publish(WAIT)
