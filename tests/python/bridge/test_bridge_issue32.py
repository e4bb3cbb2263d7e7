"""Issue 32's bridge items: an own publication the broker refuses, a full disk's WAL, paho's
mid wrap, tx error details, --check and a clean stop, the metrics endpoint under slow
clients, big tx ids, and what the broker can make the bridge do (each against a real
mosquitto on 127.0.0.1 where the broker is involved)."""
from __future__ import annotations

import json
import logging
import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import urllib.request

import pytest
from bridge_helpers import WAIT, bridge_config, need
from mosquitto import MOSQUITTO, Mosquitto


@pytest.fixture
def fap_pair():
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus:
        with Slave(bus.paths[1], id=1) as s1:
            yield bus, s1


def _line1(bus, **kw):
    return [dict({"name": "line1", "port": bus.paths[0], "protocol": "fap", "slaves": [1], "id_cycle": 0.1},
                 **kw)]


def _count(obs, pred, n, timeout=WAIT):
    """Wait until ``n`` of the observer's messages satisfy ``pred(message)`` (no JSON parse)."""
    with obs._cond:
        ok = obs._cond.wait_for(lambda: sum(1 for m in obs.messages if pred(m)) >= n, timeout)
        got = sum(1 for m in obs.messages if pred(m))
    assert ok, f"{got} of {n} messages within {timeout} s"
    return got


def _fap(*args, cwd, env=None):
    return subprocess.run([sys.executable, "-m", "fap_py", *args], capture_output=True, text=True,
                          timeout=60, cwd=str(cwd), env=env)


# -- item 5: an own publication refused ---------------------------------------------------

def test_a_refused_health_publication_is_counted_under_its_topic_not_blamed_on_rows(
        paho_mqtt, observer_factory, fap_pair, tmp_path, caplog):
    """An ACL that predates the health topic: mosquitto 2.0 answers its PUBACK with 0x87 and
    closes the connection. The refusal is counted and logged under the health topic, the
    bridge does not publish health again for a while (one reconnect, not a storm), and no
    outbox row is counted as refused because of it."""
    from fap_py.bridge import Bridge
    from fap_py.bridge.mqtt import PROBE_STRIKES

    need("mosquitto", MOSQUITTO is not None)
    bus, s1 = fap_pair
    acl = "topic read fap/#\n" + "".join(f"topic write {t}\n" for t in (
        "fap/bridge/test/status", "fap/line1/#"))   # no fap/bridge/test/health
    caplog.set_level(logging.INFO, logger="fap_py.bridge")
    with Mosquitto(str(tmp_path / "broker"), acl=acl) as broker:
        obs = observer_factory(broker.port, v5=True)
        with Bridge(bridge_config(broker.port, str(tmp_path / "state"), _line1(bus))) as bridge:
            assert bridge.wait_connected(WAIT)
            for i in range(20):
                s1.send(bytes([i]), timeout=WAIT)
            _count(obs, lambda m: m.topic == "fap/line1/1/rx", 20)        # every allowed row arrives
            (st,) = obs.wait_for("fap/line1/stats",
                                 lambda d: d["broker"].get("refused_own", {}).get("fap/bridge/test/health"))
            assert st["broker"]["refused"] == {}        # no row blamed: none refused, none dropped
            bridge._publish_health()                    # held back after the refusal: not sent
            obs.wait_for("fap/line1/stats", lambda d: d["seq"] > st["seq"] + 3)
            # refused with its PUBACK: one reconnect; the PUBACK lost with the socket: one per strike
            assert bridge.link.connects <= 1 + PROBE_STRIKES and bridge.link.connected, bridge.link.connects
            assert bridge.link.refused_own == {"fap/bridge/test/health": 1}
            assert bridge.link.refused_pubs == {}
    assert not obs.matching("fap/bridge/test/health")
    own = [r for r in caplog.records if "own publication on fap/bridge/test/health" in r.getMessage()]
    assert len(own) == 1 and own[0].levelno == logging.ERROR
    assert not any("refused publication seq" in r.getMessage() for r in caplog.records)


# -- item 7: paho's mid wraps ----------------------------------------------------------------

def test_a_mid_reused_after_the_wrap_never_acknowledges_a_row(broker, observer_factory, fap_pair, tmp_path):
    """Own publications (health) are answered under mids 65534, 65535, 1, 2 (paho's counter
    wraps); 65,535 publications later (simulated: the counter set back) an outbox row goes out
    under 65534 while the broker is frozen: it must stay unacknowledged until its own PUBACK."""
    from fap_py.bridge import Bridge

    bus, s1 = fap_pair
    obs = observer_factory(broker.port)
    with Bridge(bridge_config(broker.port, str(tmp_path / "state"), _line1(bus))) as bridge:
        assert bridge.wait_connected(WAIT)
        link = bridge.link
        with link._cond:      # whatever the start published is answered first
            assert link._cond.wait_for(lambda: bridge.store.pending == 0 and not link._inflight, WAIT)
        infos = []
        real = link.client.publish

        def spy(*a, **kw):
            info = real(*a, **kw)
            infos.append(info)
            return info

        link.client.publish = spy
        link.client._last_mid = 65533
        for _ in range(4):
            link.publish_now(link.health_topic, b'{"test":1}')
        assert [i.mid for i in infos] == [65534, 65535, 1, 2]
        for i in infos:
            i.wait_for_publish(WAIT)                  # answered by the broker
        assert len(link._early) == 0                  # nothing kept for a later owner
        assert broker.proc is not None
        os.kill(broker.proc.pid, signal.SIGSTOP)      # no PUBACK can come now
        try:
            link.client._last_mid = 65533             # 65,535 publications later
            before = len(infos)
            bridge.rx("line1", 1, {"data": "abcd"})
            with link._cond:
                assert link._cond.wait_for(lambda: len(infos) > before, WAIT)
            assert infos[before].mid == 65534
            with link._cond:     # in paho's hands, waiting for its PUBACK, still in the outbox
                assert [t for _, t in link._inflight.values()].count("fap/line1/1/rx") == 1
                assert not link._acked
            assert [t for _, t, _, _ in bridge.store.after(0, 1000)].count("fap/line1/1/rx") == 1
        finally:
            os.kill(broker.proc.pid, signal.SIGCONT)
        obs.wait_for("fap/line1/1/rx", lambda d: d["data"] == "abcd")
        assert link.drain(WAIT) and link.refused_pubs == {}
        assert len(link._early) == 0


# -- item 6: the WAL on a small filesystem ----------------------------------------------------

@pytest.fixture
def tiny_tmpfs(tmp_path):
    """A 1 MiB tmpfs (root only)."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / "tmpfs"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True,
                         text=True, timeout=30)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], timeout=30)


def test_the_wal_stays_bounded_on_a_small_disk_and_recovers_after_it_filled(
        broker, observer_factory, fap_pair, tiny_tmpfs):
    """1 MiB of disk, a broker that takes everything: 1,200 rows of 600+ bytes go through the
    outbox without one failing (the WAL is checkpointed and cut back, sqlite's default let it
    grow to 4 MB); then, the broker away, the disk is filled by someone else, and once the
    space returns the outbox works again by itself, delivers, and its WAL is cut back."""
    from fap_py.bridge import Bridge

    bus, s1 = fap_pair
    obs = observer_factory(broker.port, "fap/line1/1/rx")
    state = tiny_tmpfs / "state"
    with Bridge(bridge_config(broker.port, str(state), _line1(bus))) as bridge:
        assert bridge.wait_connected(WAIT)
        wal = bridge.store.path + "-wal"
        link, n = bridge.link, 0
        for _ in range(60):
            bridge.rx_many("line1", [(1, {"data": f"{n + i:04x}" + "ab" * 300}) for i in range(20)])
            n += 20
            with link._cond:
                assert link._cond.wait_for(lambda: bridge.store.pending < 100, WAIT)
        _count(obs, lambda m: m.topic == "fap/line1/1/rx", n)
        assert bridge.not_stored == 0, bridge.store_error
        assert os.path.getsize(wal) <= 256 << 10, os.path.getsize(wal)
        # the broker goes away (the rows stay on disk) and someone else fills the disk
        broker.stop()
        with link._cond:
            assert link._cond.wait_for(lambda: not link.connected, WAIT)
        ballast = tiny_tmpfs / "ballast"
        fd = os.open(ballast, os.O_WRONLY | os.O_CREAT)
        try:
            with pytest.raises(OSError, match="No space"):
                while True:
                    os.write(fd, b"\0" * 4096)
        finally:
            os.close(fd)
        for _ in range(2000):
            bridge.rx_many("line1", [(1, {"data": "cd" * 300})] * 5)
            if bridge.not_stored:
                break
        assert bridge.not_stored > 0 and bridge.store_error is not None
        ballast.unlink()                          # space returns, then the broker
        bridge.rx("line1", 1, {"data": "ee"})
        assert bridge.store_error is None
        broker.start()
        with link._cond:
            assert link._cond.wait_for(lambda: bridge.store.pending == 0, WAIT)
        _count(obs, lambda m: m.topic == "fap/line1/1/rx" and b'"data":"ee"' in m.payload, 1)
        assert link.drain(WAIT)
        # checkpointed and cut back (stats rows keep coming: a few frames past the limit at most)
        assert os.path.getsize(wal) <= 256 << 10, (os.path.getsize(wal), bridge.store.wal_limit)


# -- items 8, 16, 17: tx ---------------------------------------------------------------------

def test_tx_errors_name_their_id_echo_the_payload_and_use_up_no_id(broker, observer_factory, fap_pair,
                                                                   tmp_path):
    from fap_py.bridge import Bridge
    from fap_py.bridge.bridge import ID_MAX

    bus, s1 = fap_pair
    obs = observer_factory(broker.port)
    buses = _line1(bus) + [{"name": "gone", "port": str(tmp_path / "nope"), "protocol": "fap",
                            "slaves": [1], "reopen_interval": 60}]
    with Bridge(bridge_config(broker.port, str(tmp_path / "state"), buses)) as bridge:
        assert bridge.wait_connected(WAIT)

        def error_of(topic, doc):
            obs.publish(topic, doc)
            tid = doc.get("id") if isinstance(doc, dict) else None
            (e,) = obs.wait_for(topic.replace("/tx", "/error"),
                                lambda d: d["id"] == tid and d.get("payload_bytes") is not None)
            return e

        e = error_of("fap/line1/99/tx", {"id": "far", "data": "00"})             # out of range
        assert "outside" in e["error"]
        e = error_of("fap/gone/1/tx", {"id": "away", "data": "00"})              # unavailable bus
        assert "unavailable" in e["error"]
        e = error_of("fap/line1/2/tx", {"id": "stranger", "data": "00"})         # not in slaves
        assert "not one of this bus's slaves" in e["error"]
        for doc, words in (({"id": "hex", "data": "zz"}, "not hex"),
                           ({"id": "empty", "data": ""}, "0 bytes"),
                           ({"id": "long", "data": "00" * 1025}, "1025 bytes"),
                           ({"id": "op", "op": "read", "data": "00"}, "only sends")):
            e = error_of("fap/line1/1/tx", doc)
            assert words in e["error"] and e["payload"] == json.dumps(doc)[:256], e
        obs.publish("fap/line1/1/tx", "hello")
        (e,) = obs.wait_for("fap/line1/1/error", lambda d: d.get("payload") == "hello")
        assert e["error"].startswith("TxError: payload is not JSON") and "JSONDecodeError" not in e["error"]
        obs.publish("fap/line1/1/tx", {"id": "x" * (ID_MAX + 1), "data": "00"})   # item 16
        obs.wait_for("fap/line1/1/error", lambda d: f"at most {ID_MAX}" in d["error"])
        (st,) = obs.wait_for("fap/line1/stats", lambda d: d["tx_refused"] == 9)
        assert st["bridge"]["tx_errors"] == 0
        obs.publish("fap/line1/1/tx", {"id": "hex", "data": "01"})   # the refused tx's id is free
        obs.wait_for("fap/line1/stats", lambda d: d["bridge"]["tx"] == 1)
        assert bridge.duplicates == 0


def test_big_tx_ids_do_not_grow_the_state_file(broker, observer_factory, fap_pair, tmp_path):
    """600 ids of 60 kB grew the state file by 73 MB: ids past ID_MAX are refused, not kept."""
    from fap_py.bridge import Bridge
    from fap_py.bridge.bridge import ID_MAX

    bus, s1 = fap_pair
    obs = observer_factory(broker.port)
    with Bridge(bridge_config(broker.port, str(tmp_path / "state"), _line1(bus))) as bridge:
        assert bridge.wait_connected(WAIT)
        for i in range(100):
            obs.c.publish("fap/line1/1/tx", json.dumps({"id": f"{i:03d}" + "i" * 60_000, "data": "00"}), qos=1)
        obs.publish("fap/line1/1/tx", {"id": "k" * ID_MAX, "data": "00"})    # the longest kept
        obs.wait_for("fap/line1/stats", lambda d: d["tx_refused"] == 100 and d["bridge"]["tx"] == 1)
        db = sqlite3.connect(bridge.store.path)
        try:
            kept, n = db.execute("SELECT SUM(LENGTH(id)), COUNT(*) FROM seen").fetchone()
        finally:
            db.close()
        assert n == 1 and kept < 200, (kept, n)


def test_home_assistant_online_floods_are_coalesced(broker, observer_factory, fap_pair, tmp_path):
    """300 "online" messages: one republication at once, the rest folded into one later (30 s),
    not 300; a FAP node has no reply-time, errors or timeouts entities (item 9)."""
    from fap_py.bridge import Bridge

    bus, s1 = fap_pair
    obs = observer_factory(broker.port, "#")
    with Bridge(bridge_config(broker.port, str(tmp_path / "state"), _line1(bus, homeassistant=True))) as bridge:
        assert bridge.wait_connected(WAIT)
        configs = lambda m: m.topic.startswith("homeassistant/") and m.topic.endswith("/config")  # noqa: E731
        first = _count(obs, configs, 6)
        keys = {m.topic.split("/")[-2] for m in obs.messages if configs(m)}
        assert keys == {"status", "state", "last_seen", "last_message", "messages", "bus_crc_errors"}
        for _ in range(300):
            obs.c.publish("homeassistant/status", b"online", qos=1)
        obs.publish("fap/line1/1/tx", {"id": "marker", "data": "zz"})    # after the 300, in order
        obs.wait_for("fap/line1/1/error", lambda d: d["id"] == "marker")
        with obs._cond:
            n = sum(1 for m in obs.messages if configs(m))
        assert first == 6 and n == 12, n
        ha = bridge.output("homeassistant")
        assert ha.republish.runs == 1 and ha.republish.coalesced == 299


def test_rebirth_floods_are_coalesced_and_bad_commands_counted(broker, observer_factory, fap_pair, tmp_path):
    pytest.importorskip("google.protobuf")
    from fap_py.bridge import Bridge
    from fap_py.bridge.config import from_dict
    from fap_py.bridge.sparkplug import BOOLEAN, REBIRTH, encode

    bus, s1 = fap_pair
    obs = observer_factory(broker.port, "spBv1.0/#")
    cfg = from_dict({"broker": {"url": f"mqtt://127.0.0.1:{broker.port}", "reconnect_min": 0.05},
                     "bridge": {"host": "sp", "state_dir": str(tmp_path / "state"), "stats_interval": 0.2},
                     "metrics": {"listen": "127.0.0.1:0"}, "sparkplug": {"group_id": "g"},
                     "bus": _line1(bus, sparkplug=True)})
    with Bridge(cfg) as bridge:
        assert bridge.wait_connected(WAIT)
        births = lambda m: m.topic == "spBv1.0/g/NBIRTH/sp"   # noqa: E731
        _count(obs, births, 1)
        cmd = encode([(REBIRTH, BOOLEAN, True)], None)
        for _ in range(300):
            obs.c.publish("spBv1.0/g/NCMD/sp", cmd, qos=0)
        obs.c.publish("spBv1.0/g/NCMD/sp", b"\xff\xff not protobuf", qos=0).wait_for_publish(WAIT)
        sp = bridge.output("sparkplug")
        with obs._cond:   # the marker is processed after the 300 (one connection, in order)
            assert obs._cond.wait_for(lambda: sp.invalid_commands == 1 and sp.rebirths.requests == 300, WAIT)
        assert sp.rebirths.runs == 1 and sp.births == 2
        body = urllib.request.urlopen(f"http://127.0.0.1:{bridge.output('metrics').port}/metrics", timeout=WAIT).read()
        assert b"fap_bridge_sparkplug_invalid_commands_total 1.0" in body


# -- item 15: the metrics endpoint ---------------------------------------------------------

def test_slow_metrics_clients_cost_no_thread_and_a_scrape_still_works(broker, observer_factory, fap_pair,
                                                                      tmp_path):
    pytest.importorskip("prometheus_client")
    from fap_py.bridge import Bridge
    from fap_py.bridge.config import from_dict
    from fap_py.bridge.metrics import MAX_CLIENTS, MetricsServer

    bus, s1 = fap_pair
    obs = observer_factory(broker.port)
    cfg = from_dict({"broker": {"url": f"mqtt://127.0.0.1:{broker.port}", "reconnect_min": 0.05},
                     "bridge": {"host": "test", "state_dir": str(tmp_path / "state"), "stats_interval": 0.2},
                     "metrics": {"listen": "127.0.0.1:0"}, "bus": _line1(bus)})
    with Bridge(cfg) as bridge:
        assert bridge.wait_connected(WAIT)
        threads = threading.active_count()
        fds = len(os.listdir("/proc/self/fd"))
        slow = []
        try:
            for _ in range(200):                      # connect and never send
                slow.append(socket.create_connection(("127.0.0.1", bridge.output('metrics').port), timeout=WAIT))
            body = urllib.request.urlopen(f"http://127.0.0.1:{bridge.output('metrics').port}/metrics",
                                          timeout=WAIT).read()
            assert b"fap_bridge_bus_up" in body
            assert threading.active_count() <= threads + 1
            assert bridge.output('metrics').clients <= MAX_CLIENTS
            # the test's own 200 sockets, and at most MAX_CLIENTS on the bridge's side
            assert len(os.listdir("/proc/self/fd")) <= fds + 200 + MAX_CLIENTS + 5
            s1.send(b"\x42", timeout=WAIT)           # the bus side goes on
            obs.wait_for("fap/line1/1/rx", lambda d: d["data"] == "42")
        finally:
            for s in slow:
                s.close()
    # a client that sends nothing is closed after the timeout
    server = MetricsServer(bridge, "127.0.0.1", 0, timeout=0.3)
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=WAIT) as c:
            assert c.recv(10) == b""
        assert server.timed_out == 1
    finally:
        server.close()


# -- item 9: --check, a clean stop ----------------------------------------------------------

def test_check_refuses_two_buses_on_one_port_and_takes_network_ports(tmp_path):
    base = f"[bridge]\nstate_dir = '{tmp_path}/st'\n[broker]\nurl = 'mqtt://127.0.0.1'\n"
    bus = "[[bus]]\nname = '{}'\nport = '{}'\nprotocol = 'fap'\nslaves = [1]\n"
    conf = tmp_path / "b.toml"
    conf.write_text(base + bus.format("a", "/dev/null") + bus.format("b", "/dev/../dev/null"))
    res = _fap("bridge", "--config", str(conf), "--check", cwd=tmp_path)
    assert res.returncode == 2 and "bus 'b'.port" in res.stderr and "bus 'a' already uses" in res.stderr
    conf.write_text(base + bus.format("a", "tcp://127.0.0.1:4001") + bus.format("b", "rfc2217://ser2net.lan:4002")
                    + bus.format("c", "TCP://127.0.0.1:4003"))
    res = _fap("bridge", "--config", str(conf), "--check", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    conf.write_text(base + bus.format("a", "tcp://127.0.0.1:4001") + bus.format("b", "tcp://127.0.0.1:4001"))
    res = _fap("bridge", "--config", str(conf), "--check", cwd=tmp_path)
    assert res.returncode == 2 and "already uses" in res.stderr
    conf.write_text(base + bus.format("a", "ftp://127.0.0.1:4001"))
    res = _fap("bridge", "--config", str(conf), "--check", cwd=tmp_path)
    assert res.returncode == 3 and "bus 'a'.port" in res.stderr and "tcp://HOST:PORT" in res.stderr
    conf.write_text(base + "[[bus]\n")                      # broken TOML: the path once
    res = _fap("bridge", "--config", str(conf), "--check", cwd=tmp_path)
    assert res.returncode == 2 and res.stderr.count(str(conf)) == 1, res.stderr
    assert not (tmp_path / "st").exists()


def test_without_paho_no_state_file_is_created(tmp_path):
    block = ("import sys; sys.modules['paho'] = None; sys.modules['paho.mqtt'] = None; "
             "sys.modules['paho.mqtt.client'] = None; from fap_py.cli import main; sys.exit(main(sys.argv[1:]))")
    conf = tmp_path / "b.toml"
    conf.write_text("[bridge]\nhost = 'h'\nstate_dir = 'st'\n[broker]\nurl = 'mqtt://x'\n"
                    "[[bus]]\nname = 'l'\nport = 'p'\nprotocol = 'fap'\nslaves = [1]\n")
    res = subprocess.run([sys.executable, "-c", block, "bridge", "--config", str(conf)],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert res.returncode == 2 and "paho-mqtt" in res.stderr
    assert not (tmp_path / "st").exists()


def test_the_example_names_the_real_default_state_dir(monkeypatch):
    from fap_py.bridge.config import load

    example = os.path.join(os.path.dirname(__file__), "..", "..", "..", "examples", "bridge", "bridge.toml")
    example = os.path.abspath(example)
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    text = open(example).read()
    assert "else the directory of this file" in text and "else the current directory" not in text
    assert os.path.abspath(load(example).state_dir) == os.path.dirname(example)


def test_a_clean_stop_leaves_health_stopped_and_nodes_inactive(broker, observer_factory, fap_pair, tmp_path):
    from fap_py.bridge import Bridge

    bus, s1 = fap_pair
    obs = observer_factory(broker.port)
    with Bridge(bridge_config(broker.port, str(tmp_path / "state"), _line1(bus))):
        s1.send(b"\x01", timeout=WAIT)
        obs.wait_for("fap/line1/1/state", lambda d: d["state"] == "active")
        obs.wait_for("fap/bridge/test/health", lambda d: d.get("state", "running") == "running")
    late = observer_factory(broker.port, client_id="late")     # what is retained now
    late.wait_raw("fap/bridge/test/status", b"offline")
    (h,) = late.wait_for("fap/bridge/test/health")
    assert h["state"] == "stopped" and h["buses"]["line1"]["state"] == "stopped"
    (st,) = late.wait_for("fap/line1/1/state")
    assert st["state"] == "inactive" and st["last_seen"] is not None


# -- item 21: parse_url ----------------------------------------------------------------------

@pytest.mark.parametrize("url, words", [
    ("mqtt://bro\ud800ker:1883", "lone surrogate"),
    ("mqtt://" + "h" * 10_000 + ":1883", "a host of 10000 characters"),
    ("mqtt://a..b:1883", "is not a host name"),
])
def test_parse_url_refuses_what_no_broker_can_be_named(url, words):
    from fap_py.bridge.config import BridgeConfigError, parse_url

    with pytest.raises(BridgeConfigError, match=words) as info:
        parse_url(url)
    assert len(str(info.value)) < 300


class _Reason:
    def __init__(self, failure: bool, text: str) -> None:
        self.is_failure = failure
        self.text = text

    def __str__(self) -> str:
        return self.text


def test_losses_with_an_own_publication_unanswered_strike_it_never_the_rows(tmp_path, paho_mqtt):
    """The refusal's PUBACK lost with the socket: the losses are the health topic's (held
    back at the last strike), and no row is struck or probed for them."""
    from fap_py.bridge.mqtt import PROBE_STRIKES, MqttLink
    from fap_py.bridge.store import Store

    cfg = bridge_config(1, str(tmp_path), [{"name": "l", "port": "/dev/null", "protocol": "fap", "slaves": [1]}])
    with Store(str(tmp_path / "s.sqlite")) as store:
        link = MqttLink(cfg, store, lambda *a: None)
        store.put_many([("t", b"x", False)] * 3)
        for i in range(PROBE_STRIKES):
            link._inflight = {11 + i: (1, "t")}
            link._own = {50 + i: link.health_topic}
            link._connected = True
            link._on_disconnect(None, None, None, _Reason(True, "Unspecified error"), None)
            assert link.held(link.health_topic) == (i == PROBE_STRIKES - 1)
        assert not link.probing and link.refused_pubs == {} and not link._strikes
        assert link.refused_own == {link.health_topic: 1}
        assert not link.held(link.status_topic)


def test_a_refusal_raised_in_the_bus_worker_is_echoed_and_counted_refused(broker, observer_factory, tmp_path):
    """The exec async engine refuses data over its frame's size when the worker runs the tx:
    the error echoes the payload like every other refusal and counts in tx_refused."""
    from fap_py.bridge import Bridge
    from fap_py.execasync import MAX_DATA
    from fap_py.vbus import VirtualBus

    obs = observer_factory(broker.port)
    with VirtualBus(2) as bus:
        cfg = bridge_config(broker.port, str(tmp_path / "state"),
                            [{"name": "ex", "port": bus.paths[0], "protocol": "exec", "nodes": [5]}])
        with Bridge(cfg) as bridge:
            assert bridge.wait_connected(WAIT)
            doc = {"id": "big", "data": "00" * (MAX_DATA + 1)}
            obs.publish("fap/ex/5/tx", doc)
            (e,) = obs.wait_for("fap/ex/5/error", lambda d: d["id"] == "big")
            assert e["payload"] == json.dumps(doc)[:256] and e["payload_bytes"] == len(json.dumps(doc))
            obs.wait_for("fap/ex/stats", lambda d: d["tx_refused"] == 1 and d["bridge"]["tx_errors"] == 0)
