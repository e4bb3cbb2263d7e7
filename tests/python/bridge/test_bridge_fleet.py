"""The bridge in a fleet (issue 37): a list of brokers, failover and failback with the
outbox kept, MQTT 3.1.1 chosen for a broker that refuses 5 (nats-server), a list of
which none answers."""
from __future__ import annotations

import logging
import time

import pytest
from bridge_helpers import WAIT, need
from fault_proxy import wait_until
from fleet_helpers import NATS, Nats, accounting, fleet_config, rx_rows
from mosquitto import MOSQUITTO, Mosquitto, free_port


@pytest.fixture
def two_brokers(tmp_path, paho_mqtt):
    need("mosquitto", MOSQUITTO is not None)
    with Mosquitto(str(tmp_path / "a")) as a, Mosquitto(str(tmp_path / "b")) as b:
        yield a, b


def _on(bridge, index: int):
    link = bridge.link
    return lambda: link.connected and link.broker_index == index and link._gate_open


def test_failover_and_failback_keep_the_outbox(two_brokers, observer_factory, tmp_path, caplog):
    from fap_py.bridge import Bridge

    a, b = two_brokers
    caplog.set_level(logging.INFO, logger="fap_py.bridge")
    obs_a = observer_factory(a.port, "fap/#", client_id="consumer-a", clean=False)
    obs_b = observer_factory(b.port, "fap/#", client_id="consumer-b", clean=False)
    with Bridge(fleet_config([a.port, b.port], str(tmp_path / "state"))) as bridge:
        assert bridge.wait_connected(WAIT) and bridge.link.broker_index == 0
        obs_a.wait_for("fap/bridge/test/health", lambda d: d["broker"] == f"127.0.0.1:{a.port}")
        rx_rows(bridge, 0, 100)
        obs_a.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{99:06x}")

        a.stop()                                   # failover: the outbox goes on at b
        t0 = time.monotonic()
        rx_rows(bridge, 100, 100)                  # made while no broker is connected
        assert wait_until(_on(bridge, 1), WAIT)
        failover = time.monotonic() - t0
        obs_b.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{199:06x}")
        health = obs_b.wait_for("fap/bridge/test/health", lambda d: d["broker"] == f"127.0.0.1:{b.port}")[0]
        assert health["broker_index"] == 1
        stats = obs_b.wait_for("fap/line1/stats", lambda d: d["broker"]["index"] == 1)[0]
        assert stats["broker"]["switches"] == 1 and stats["broker"]["address"] == f"127.0.0.1:{b.port}"

        a.start()                                  # failback: the preferred broker answers again
        rx_rows(bridge, 200, 100)
        assert wait_until(_on(bridge, 0), WAIT)
        rx_rows(bridge, 300, 100)
        obs_a.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{399:06x}")
        assert bridge.link.drain(WAIT)
        assert bridge.link.switches == 2 and bridge.link.probes >= 1
    got_a, got_b = accounting(obs_a.messages), accounting(obs_b.messages)
    # every row exactly once by (host, seq) across the two brokers; in order at each one
    assert got_a["data"] | got_b["data"] == set(range(400))
    assert got_a["in_order"] and got_b["in_order"]
    assert set(range(100)) <= got_a["data"] and set(range(300, 400)) <= got_a["data"]
    assert set(range(100, 200)) <= got_b["data"]
    logs = caplog.text
    assert f"failover: 127.0.0.1:{a.port} (broker 1 of 2, not connected) -> 127.0.0.1:{b.port}" in logs
    assert f"failback: 127.0.0.1:{b.port} (broker 2 of 2) -> 127.0.0.1:{a.port} (broker 1 of 2)" in logs
    print(f"failover {failover:.2f} s; duplicates a={got_a['duplicates']} b={got_b['duplicates']}")
    assert failover < WAIT


def test_failback_can_be_turned_off(two_brokers, tmp_path):
    from fap_py.bridge import Bridge

    a, b = two_brokers
    cfg = fleet_config([a.port, b.port], str(tmp_path / "state"), failover={"failback": False})
    with Bridge(cfg) as bridge:
        assert bridge.wait_connected(WAIT)
        a.stop()
        assert wait_until(_on(bridge, 1), WAIT)
        a.start()
        probes = bridge.link.probes
        # several failback intervals (0.3 s) pass: no probe, no move (bounded polling of the clock)
        assert not wait_until(lambda: bridge.link.broker_index != 1, 1.5)
        assert bridge.link.probes == probes == 0


def test_no_broker_answers_clear_errors_retries_nothing_lost(paho_mqtt, observer_factory, tmp_path, caplog):
    from fap_py.bridge import Bridge

    need("mosquitto", MOSQUITTO is not None)
    caplog.set_level(logging.INFO, logger="fap_py.bridge")
    ports = [free_port(), free_port(), free_port()]
    with Bridge(fleet_config(ports, str(tmp_path / "state"))) as bridge:
        rx_rows(bridge, 0, 50)
        assert not bridge.wait_connected(1.0)
        link = bridge.link
        assert wait_until(lambda: link.switches >= 4, WAIT)    # around the list, more than once
        assert "connection refused" in link.last_error and "127.0.0.1:" in link.last_error
        assert bridge.store.pending >= 50                      # nothing lost: all in the outbox
        assert "not connected" in bridge.status_line()
        for p in ports:
            assert f"127.0.0.1:{p}: connection refused" in caplog.text
        with Mosquitto(str(tmp_path / "late"), port=ports[2]) as late:   # the last one comes up
            obs = observer_factory(late.port, "fap/#", client_id="late", clean=False)
            assert bridge.wait_connected(WAIT) and link.broker_index == 2
            rx_rows(bridge, 50, 10)
            obs.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{59:06x}")
            assert bridge.link.drain(WAIT)
            got = accounting(obs.messages)
            assert got["data"] == set(range(60)) and got["in_order"]


def test_mqtt5_refused_falls_back_to_311_on_nats(paho_mqtt, observer_factory, tmp_path, caplog):
    """nats-server's MQTT listener speaks 3.1.1 only: it answers an MQTT 5 CONNECT with
    "unsupported protocol version"; the bridge (protocol "auto") uses 3.1.1 with it."""
    from fap_py.bridge import Bridge

    need("nats-server", NATS is not None)
    caplog.set_level(logging.INFO, logger="fap_py.bridge")
    with Nats(str(tmp_path / "nats")) as nats:
        obs = observer_factory(nats.port, "fap/#", client_id="nats-consumer", clean=False)
        with Bridge(fleet_config([nats.port], str(tmp_path / "state"))) as bridge:
            assert bridge.wait_connected(WAIT)
            assert not bridge.link.v5 and bridge.link.fallbacks == 1
            rx_rows(bridge, 0, 200)
            obs.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{199:06x}")
            obs.wait_for("fap/bridge/test/health", lambda d: d["broker"] == f"127.0.0.1:{nats.port}")
            # (seen once, under a load of 10: 87 rows never acknowledged with the connection up;
            # not reproduced since: say what was stuck if it comes back)
            assert bridge.link.drain(WAIT), _stuck(bridge, nats)
        got = accounting(obs.messages)
        assert got["data"] == set(range(200)) and got["in_order"]
        assert "refuses MQTT 5: using MQTT 3.1.1" in caplog.text


def _stuck(bridge, nats) -> str:
    link = bridge.link
    with link._cond:
        return (f"outbox {bridge.store.pending}, in flight {len(link._inflight)} "
                f"(seqs {sorted(s for s, _ in link._inflight.values())[:5]}...), connected {link.connected}, "
                f"gate {link._gate_open}, own {list(link._own.values())}, probing {link.probing}, "
                f"paho queue {len(getattr(link.client, '_out_messages', {}))}; nats:\n"
                + "\n".join(nats.log[-20:]))


def test_explicit_mqtt5_is_not_downgraded(paho_mqtt, tmp_path):
    from fap_py.bridge import Bridge

    need("nats-server", NATS is not None)
    with Nats(str(tmp_path / "nats")) as nats:
        with Bridge(fleet_config([nats.port], str(tmp_path / "state"), protocol="5")) as bridge:
            assert not bridge.wait_connected(1.5)
            assert bridge.link.fallbacks == 0 and bridge.link.v5
            assert "Unsupported protocol version" in (bridge.link.last_error or "")


def test_fleet_config_is_checked(tmp_path):
    from fap_py.bridge.config import BridgeConfigError, from_dict

    base = {"bridge": {"host": "t", "state_dir": str(tmp_path)}, "bus": [{"name": "l", "port": "/dev/null",
                                                                        "protocol": "fap", "slaves": [1]}]}
    cfg = from_dict(dict(base, broker=[{"url": "mqtt://a:1883"}, {"url": "mqtts://b:8883"}],
                         failover={"failback_interval": 5}))
    assert [b.address for b in cfg.brokers] == ["a:1883", "b:8883"] and cfg.broker is cfg.brokers[0]
    assert cfg.brokers[1].tls and cfg.failover.failback and cfg.failover.failback_interval == 5.0
    single = from_dict(dict(base, broker={"url": "mqtt://a"}))
    assert single.brokers == (single.broker,) and single.broker.protocol == "auto"
    for bad, where in (([], "missing [broker]"), ([{"url": "mqtt://a"}, {"url": "mqtt://A:1883"}], "same broker"),
                       ([{"url": "mqtt://a"}, {"url": "mqtt://b", "ca": "x"}], "broker[1].ca"),
                       ([{"url": "mqtt://a", "protocol": "4"}], "broker[0].protocol"),
                       ([{"url": "mqtt://a"}, "x"], "broker[1] must be a table")):
        with pytest.raises(BridgeConfigError, match=where.replace("[", r"\[").replace("]", r"\]")):
            from_dict(dict(base, broker=bad))
    with pytest.raises(BridgeConfigError, match="failover.attempts"):
        from_dict(dict(base, broker={"url": "mqtt://a"}, failover={"attempts": 0}))
    with pytest.raises(BridgeConfigError, match="failover"):
        from_dict(dict(base, broker={"url": "mqtt://a"}, failover={"nope": 1}))


def test_the_sparkplug_edge_node_follows_the_failover(two_brokers, observer_factory, tmp_path):
    """The Sparkplug connection goes where the main link went: births on the new broker."""
    import dataclasses

    from fap_py.bridge import Bridge

    a, b = two_brokers
    obs_b = observer_factory(b.port, "spBv1.0/#", client_id="sp-b")
    cfg = fleet_config([a.port, b.port], str(tmp_path / "state"), sparkplug={"group_id": "plant"})
    cfg = dataclasses.replace(cfg, buses=(dataclasses.replace(cfg.buses[0], sparkplug=True),))
    with Bridge(cfg) as bridge:
        node = bridge.output("sparkplug").node
        assert bridge.wait_connected(WAIT) and wait_until(lambda: node.connected, WAIT)
        assert node.broker.port == a.port
        a.stop()
        assert wait_until(_on(bridge, 1), WAIT)
        with obs_b._cond:
            assert obs_b._cond.wait_for(lambda: any(m.topic == "spBv1.0/plant/NBIRTH/test"
                                                    for m in obs_b.messages), WAIT)
        assert node.broker.port == b.port and node.connected


@pytest.mark.parametrize("attempts", [1, 2])
def test_a_half_open_broker_is_left_for_the_next(two_brokers, observer_factory, tmp_path, caplog, attempts):
    """The preferred broker's link goes half-open (no FIN, no RST: its side closed, ours
    silent) with rows in flight: no PUBACK within ack_timeout is a failed attempt; with
    attempts = 2 a new connection, which gets no CONNACK within connect_timeout (the second)
    -> the next broker; every row delivered once."""
    from fault_proxy import FaultProxy

    from fap_py.bridge import Bridge

    a, b = two_brokers
    caplog.set_level(logging.INFO, logger="fap_py.bridge")
    with FaultProxy(a.port) as proxy:
        obs_a = observer_factory(a.port, "fap/#", client_id="consumer-a", clean=False)
        obs_b = observer_factory(b.port, "fap/#", client_id="consumer-b", clean=False)
        cfg = fleet_config([proxy.port, b.port], str(tmp_path / "state"), keepalive=60,
                           ack_timeout=0.5, connect_timeout=0.5,
                           failover={"failback": False, "attempts": attempts})
        with Bridge(cfg) as bridge:
            assert bridge.wait_connected(WAIT)
            rx_rows(bridge, 0, 50)
            obs_a.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{49:06x}")
            proxy.set("half_open")
            t0 = time.monotonic()
            rx_rows(bridge, 50, 50)               # in flight into the silence
            assert wait_until(_on(bridge, 1), WAIT)
            moved = time.monotonic() - t0
            obs_b.wait_for("fap/line1/1/rx", lambda d: d["data"] == f"{99:06x}")
            assert bridge.link.drain(WAIT)
            assert bridge.link.stalls == attempts
        got_a, got_b = accounting(obs_a.messages), accounting(obs_b.messages)
        assert got_a["data"] | got_b["data"] == set(range(100)) and got_b["in_order"]
        assert "no acknowledgement for 0.5 s" in caplog.text
        assert ("no CONNACK within 0.5 s" in caplog.text) == (attempts == 2)
        print(f"half-open failover {moved:.2f} s (keepalive 60 s would have taken 90)")
