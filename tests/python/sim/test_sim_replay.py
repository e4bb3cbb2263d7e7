"""``fap sim --replay``: a capture made by the virtual bus answers the same requests with the
recorded bytes and delays; a request not in the capture is counted and gets no reply."""
from __future__ import annotations

import time

import pytest

from fap_py import execasync, mikroc
from fap_py.errors import FapError
from fap_py.sim import Replay, ReplayError, Sim, loads
from fap_py.sim._replay import build_table
from fap_py.vbus import VirtualBus, read_capture

from .conftest import cli


def _record(tmp_path, protocol: str, nodes: str, exchange, fault=None) -> tuple:
    cap = str(tmp_path / f"{protocol}.cap")
    with VirtualBus(ports=2, baud=115200, capture=cap) as bus:
        cfg = loads(f'[[bus]]\nprotocol = "{protocol}"\nbaud = 115200\nport = "{bus.paths[1]}"\n{nodes}')
        with Sim(cfg) as sim:
            if fault:
                sim.add_fault(**fault)
            recorded = exchange(bus.paths[0])
    return cap, recorded


def _exec_exchange(path: str) -> list:
    with execasync.Master(path, 115200, timeout=0.5, retries=0) as m:
        return [m.transact(n, bytes([n, i])) for i in range(3) for n in (1, 2, 3)]


NODES = '[[bus.node]]\nrange = [1, 3]\nanswer = "value"\nvalue = { kind = "counter", start = 500 }\n'


def test_exec_replay_is_byte_exact_with_delays(tmp_path):
    cap, recorded = _record(tmp_path, "exec", NODES, _exec_exchange,
                            fault={"kind": "late_reply", "node": 2, "ms": 60})
    table = build_table(read_capture(cap), "exec")
    assert table.requests == 9 and len(table.entries) == 9
    delays = {req[2]: d for req, ((_, d),) in table.entries.items()}   # node byte -> delay
    assert delays[2] >= 0.055
    with Replay(cap, "exec") as rp, execasync.Master(rp.master_port, 115200, timeout=0.5, retries=0) as m:
        got, took = [], {}
        for i in range(3):
            for n in (1, 2, 3):
                t0 = time.monotonic()
                got.append(m.transact(n, bytes([n, i])))
                took[n] = time.monotonic() - t0
        assert got == recorded
        assert took[2] >= 0.055                     # the recorded delay, not an immediate reply
        with pytest.raises(execasync.NoReplyError):
            m.transact(9, b"never recorded")
        s = rp.responder.summary()
        assert s["matched"] == 9 and s["unmatched"] == 1 and s["replies"] == 9


def test_mikroc_replay_and_cli(tmp_path):
    def exchange(path):
        with mikroc.Master(path, 115200) as m:
            return [m.request(a, bytes([a]), timeout=1).data for a in (0, 7, 255)]

    cap, recorded = _record(tmp_path, "mikroc", '[[bus.node]]\naddress = 0\n[[bus.node]]\naddress = 7\n'
                            '[[bus.node]]\naddress = 255\n', exchange)
    assert recorded == [b"\x00", b"\x07", b"\xff"]
    from .conftest import SimProcess
    sim = SimProcess("--replay", cap, "--protocol", "mikroc", "--baud", "115200")
    try:
        with mikroc.Master(sim.port(), 115200) as m:
            assert [m.request(a, bytes([a]), timeout=1).data for a in (0, 7, 255)] == recorded
        final = sim.stop()
        assert final["event"] == "stopped" and final["matched"] == 3 and final["unmatched"] == 0
    finally:
        sim.kill()


def test_replay_errors(tmp_path):
    empty = tmp_path / "e.cap"
    empty.write_text("# fap-vbus-capture 1 ports=2 baud=9600 echo=0 seed=0\n")
    with pytest.raises(ReplayError, match="no bytes"):
        build_table(read_capture(str(empty)), "exec")
    r = cli("sim", "--replay", str(empty))
    assert r.returncode == 2 and "--protocol" in r.stderr
    r = cli("sim", "--replay", str(empty), "--protocol", "exec")
    assert r.returncode == 2 and "no bytes" in r.stderr
    r = cli("sim", "--replay", str(tmp_path / "missing.cap"), "--protocol", "exec")
    assert r.returncode in (2, 3) and "missing.cap" in r.stderr


def test_g485_replay(tmp_path):
    from fap_py.g485 import G485Master

    def exchange(path):
        with G485Master(path, 115200, timeout=0.2, retries=0) as gm:
            gm.write(5, 20, b"\x33")
            return [gm.read(5, 20, 1), gm.read(5, 7, 1), gm.read(126, 7, 1)]

    cap, recorded = _record(tmp_path, "g485", "[[bus.node]]\naddress = 5\n[[bus.node]]\naddress = 126\n",
                            exchange)
    assert recorded == [b"\x33", b"\x05", b"\x7e"]
    with Replay(cap, "g485") as rp:
        assert exchange(rp.master_port) == recorded
        assert rp.responder.summary()["unmatched"] == 0


def test_learn_round_trip(tmp_path):
    """A capture of exec nodes -> a learned config -> a sim from it answers the same requests
    with the recorded replies."""
    cap, recorded = _record(tmp_path, "exec", NODES, _exec_exchange)
    out = tmp_path / "learned.toml"
    r = cli("sim", "--learn", cap, "--protocol", "exec", "-o", str(out))
    assert r.returncode == 0, r.stderr
    assert cli("sim", "--check", str(out)).returncode == 0
    from fap_py.sim import load
    with Sim(load(str(out))) as sim:
        assert sim.buses[0].addresses == [1, 2, 3]
        assert _exec_exchange(sim.buses[0].master_port) == recorded
    r = cli("sim", "--learn", cap, "--protocol", "exec")
    assert r.stdout.startswith("# learned by fap sim --learn")


def test_learn_g485_registers(tmp_path):
    from fap_py.g485 import G485Master

    def exchange(path):
        with G485Master(path, 115200, timeout=0.2, retries=0) as gm:
            gm.write(5, 20, b"\x33")
            return [gm.read(5, 1, 7), gm.read(5, 20, 2)]

    cap, recorded = _record(tmp_path, "g485", "[[bus.node]]\naddress = 5\nregisters = "
                            "[{ register = 21, access = \"R\", initial = 9 }]\n", exchange)
    from fap_py.sim._learn import learn
    text = learn(read_capture(cap), "g485")
    assert "identity = [11, 1, 1, 1, 1]" in text and "{ register = 21, initial = 9 }" in text
    with Sim(loads(text)) as sim:
        assert exchange(sim.buses[0].master_port) == recorded


def test_replay_refuses_bad_arguments(tmp_path):
    """Replay (fap_py.sim.Replay) checks baud and master_port: an empty baud or a bool
    port index used to be taken (as "the capture's baud" and port 1)."""
    from fap_py.errors import InvalidTypeError, InvalidValueError

    cap, _ = _record(tmp_path, "exec", NODES, lambda p: _exec_exchange(p)[:1])
    for bad in ("", "9600", 1.5, -1, True):
        with pytest.raises((InvalidTypeError, InvalidValueError)):
            Replay(cap, "exec", baud=bad)
    for bad in (True, -1, 10**6, "0", 1.5):
        with pytest.raises((InvalidTypeError, InvalidValueError)):
            Replay(cap, "exec", master_port=bad)
    for bad in (5, None, b"exec", "nope"):
        with pytest.raises(FapError):
            Replay(cap, bad)


def test_replay_of_a_monitor_pcap(tmp_path):
    """A bus recorded by the virtual bus, turned into a pcap by `fap monitor --capture --pcap`
    (each packet names its sender port), replays byte-exact; a pcap without ports is refused."""
    cap, recorded = _record(tmp_path, "exec", NODES, _exec_exchange)
    pcap = str(tmp_path / "exec.pcap")
    r = cli("monitor", "--capture", cap, "--protocol", "exec", "--pcap", pcap, "-q")
    assert r.returncode == 0, r.stderr
    from fap_py.monitor.pcap import read_pcap
    frames = list(read_pcap(pcap))
    assert len(frames) == 18 and {f.port for f in frames} == {0, 1} and all(f.ok for f in frames)
    with Replay(pcap, "exec") as rp, execasync.Master(rp.master_port, 115200, timeout=0.5, retries=0) as m:
        got = [m.transact(n, bytes([n, i])) for i in range(3) for n in (1, 2, 3)]
        assert got == recorded
        assert rp.responder.summary()["matched"] == 9
    # learn reads the pcap too
    r = cli("sim", "--learn", pcap, "--protocol", "exec")
    assert r.returncode == 0 and "address = 1" in r.stdout, r.stderr
    # a pcap whose packets name no sender (a raw stream piped in) cannot be replayed
    raw = str(tmp_path / "raw.pcap")
    with open(cap.replace(".cap", ".raw"), "wb") as fh:
        fh.write(b"".join(f.raw for f in frames))
    import subprocess

    from .conftest import fap_argv
    with open(cap.replace(".cap", ".raw"), "rb") as fh:
        p = subprocess.run(fap_argv("monitor", "--protocol", "exec", "--pcap", raw, "-q"), stdin=fh,
                           capture_output=True, timeout=30)
    assert p.returncode == 0, p.stderr
    with pytest.raises(ReplayError, match="do not name their sender port"):
        Replay(raw, "exec")
    # not a pcap of the monitor's link type: one clear error
    other = tmp_path / "other.pcap"
    other.write_bytes(bytes.fromhex("d4c3b2a1020004000000000000000000ffff000001000000"))
    with pytest.raises(FapError, match="link type 1"):
        Replay(str(other), "exec")
