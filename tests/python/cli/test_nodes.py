"""Node commands through the entry point, against real nodes on a virtual bus."""
from __future__ import annotations

import io
import json
import signal
import subprocess
import threading
from typing import List

from fap_py import RS485, RS485Mode, execasync, mikroc
from fap_py import Slave as FapSlave
from fap_py.g485 import SimDevice, Simulator

from .conftest import fap_cmd

LINE = RS485(mode=RS485Mode.NONE)
NONE = ("--rs485", "none")


def _json(lines: List[str]) -> List[dict]:
    return [json.loads(line) for line in lines]


def _start(*args: str) -> subprocess.Popen:
    return subprocess.Popen(fap_cmd(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _stop(p: subprocess.Popen) -> List[str]:
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0, err
    return out.splitlines()


def test_exec_master_and_slave_processes(fap, bus) -> None:
    slave = _start("exec", "slave", "--port", bus.paths[1], *NONE, "--node", "5", "--json")
    try:
        ready = json.loads(slave.stdout.readline())       # readiness line before any request
        assert ready == {"event": "ready", "node": 5, "port": bus.paths[1], "baud": 115200}
        r = fap("exec", "master", "--port", bus.paths[0], *NONE, "--node", "5", "--json",
                "--count", "2", "--interval", "0", "--timeout", "1", "0102", "aa bb")
        assert r.code == 0, r.err
        objs = _json(r.lines())
        assert [(o["event"], o.get("seq"), o.get("data")) for o in objs[:4]] == [
            ("reply", 0, "0102"), ("reply", 1, "aabb"), ("reply", 2, "0102"), ("reply", 3, "aabb")]
        assert objs[-1]["event"] == "stats" and objs[-1]["transactions"] == 4
        r = fap("exec", "master", "--port", bus.paths[0], *NONE, "--node", "5", "--timeout", "1",
                "03")
        assert r.lines()[0] == "node 5 seq 0: 03"   # a new master starts at seq 0
    finally:
        lines = _stop(slave)
    objs = _json(lines)
    assert [o["data"] for o in objs if o["event"] == "request"] == ["0102", "aabb", "0102",
                                                                       "aabb", "03"]
    assert objs[-1]["event"] == "stats" and objs[-1]["processed"] == 5


def test_exec_master_reads_stdin(fap, bus, monkeypatch) -> None:
    with execasync.Slave(bus.paths[1], node=7, handler=lambda q: q.data[::-1], rs485=LINE).start():
        monkeypatch.setattr("sys.stdin", io.StringIO("0102\n\n0304\n"))
        r = fap("exec", "master", "--port", bus.paths[0], *NONE, "--node", "7", "--timeout", "1",
                "-")
    assert r.code == 0 and r.lines()[:2] == ["node 7 seq 0: 02 01", "node 7 seq 1: 04 03"]


def test_exec_scan_finds_the_nodes(fap, bus) -> None:
    with execasync.Slave(bus.paths[1], node=3, handler=lambda q: b"hi", rs485=LINE).start(), \
            execasync.Slave(bus.paths[2], node=6, handler=lambda q: b"", rs485=LINE).start():
        r = fap("exec", "scan", "--port", bus.paths[0], *NONE, "--last", "8", "--timeout", "0.5",
                "--json")
        assert r.code == 0, r.err
        objs = _json(r.lines())
        assert [(o["node"], o["reply"]) for o in objs if o["event"] == "found"] == [(3, "6869"),
                                                                                   (6, "")]
        assert objs[-1] == {"event": "summary", "found": [3, 6], "tried": 8}
    r = fap("exec", "scan", "--port", bus.paths[0], *NONE, "--first", "9", "--last", "9")
    assert r.code == 1 and r.lines()[-1] == "0 of 1 nodes answered"
    assert fap("exec", "scan", "--port", bus.paths[0], "--first", "5", "--last", "2").code == 2


def test_exec_decode_says_truncated(fap) -> None:
    frame = execasync.encode(5, b"ABC", 1)
    r = fap("exec", "decode", frame.hex())
    assert r.code == 0 and r.out == "node 5 seq 1 GOOD data 414243\n"
    r = fap("exec", "decode", frame[:-3].hex())
    assert r.code == 1 and "truncated frame: " in r.out and "input ends inside a frame" in r.out
    r = fap("exec", "decode", "--json", (frame + frame[:4]).hex())
    objs = _json(r.lines())
    assert r.code == 1 and objs[0]["status"] == "good" and objs[1]["status"] == "truncated"
    assert objs[1]["bytes"] == frame[:4].hex()
    r = fap("exec", "decode", "00ff")
    assert r.code == 1 and "no exec async frame" in r.out
    r = fap("exec", "encode", "--json", "--node", "5", "--seq", "1", "414243")
    assert json.loads(r.out)["frame"] == frame.hex()


def test_fap_master_command_with_a_slave(fap, bus) -> None:
    with FapSlave(bus.paths[1], id=3, rs485=LINE) as s:
        s.send(b"temp=21.5")
        r = fap("fap", "master", "--port", bus.paths[0], *NONE, "--slaves", "3",
                "--id-cycle", "0.05", "--text", "--json", "--interval", "0.5", "hello")
        assert r.code == 0, r.err
        objs = _json(r.lines())
        events = [o["event"] for o in objs]
        assert events[0] == "ready" and "slave_active" in events and events[-1] == "stats"
        assert {"event": "tx", "to": 3, "data": b"hello".hex()} in objs
        assert {"event": "rx", "from": 3, "data": b"temp=21.5".hex()} in objs
        assert s.recv(timeout=10).data == b"hello"
        assert objs[-1]["data_tx"] == 1 and objs[-1]["data_rx"] == 1


def test_fap_slave_command_with_a_master(fap, bus) -> None:
    from fap_py import Master

    with Master(bus.paths[0], slaves=[4], id_cycle=0.05, rs485=LINE) as m:
        r = fap("fap", "slave", "--port", bus.paths[1], *NONE, "--id", "4", "--text",
                "--interval", "0.2", "reading 1")
        assert r.code == 0, r.err
        assert r.lines()[0].startswith("ready: FAP slave 4 on ")
        assert "-> master: " in r.out
        assert m.recv(timeout=10).data == b"reading 1"


def test_mikroc_master_and_slave(fap, bus) -> None:
    result: List = []
    t = threading.Thread(target=lambda: result.append(fap(
        "mikroc", "slave", "--port", bus.paths[1], *NONE, "--address", "5", "--json",
        "--max-requests", "2", "--reply", "c0ffee")))
    # the slave command runs in this process: talk to it with a library master
    t.start()
    try:
        with mikroc.Master(bus.paths[0], rs485=LINE) as m:
            replies = []
            for _ in range(200):        # until the slave command has opened its port
                try:
                    replies.append(m.request(5, b"\x01", timeout=0.05))
                except Exception:
                    continue
                if len(replies) == 2:
                    break
        assert [x.data for x in replies] == [b"\xc0\xff\xee"] * 2
    finally:
        t.join(30)
    assert result and result[0].code == 0
    objs = _json(result[0].lines())
    assert objs[0]["event"] == "ready" and objs[-1]["event"] == "stats"
    with mikroc.Slave(bus.paths[1], address=9, rs485=LINE) as s:
        done = threading.Event()

        def answer() -> None:
            while not done.is_set():
                try:
                    msg = s.receive(0.1)
                except Exception:
                    continue
                s.send(msg.data[::-1])

        th = threading.Thread(target=answer)
        th.start()
        try:
            r = fap("mikroc", "master", "--port", bus.paths[0], *NONE, "--address", "9",
                    "--timeout", "2", "--json", "010203")
        finally:
            done.set()
            th.join(10)
    assert r.code == 0, r.err
    assert _json(r.lines())[0] == {"event": "reply", "address": 9, "data": "030201"}


def test_g485_scan_and_read(fap, bus) -> None:
    with Simulator(bus.paths[1], [SimDevice(2), SimDevice(5)]):
        # generous timeouts: a late reply on a loaded machine would confuse the next request
        r = fap("g485", "read", "--port", bus.paths[0], "--address", "5", "--register", "1",
                "--registers", "2", "--count", "2", "--interval", "0", "--timeout", "2",
                "--json")
        assert r.code == 0 and len(r.lines()) == 3, r.err
        replies = _json(r.lines())
        assert [o["event"] for o in replies] == ["reply", "reply", "summary"]   # issue 25: event keys
        assert replies[0]["values"] == replies[1]["values"]
        assert replies[2] == {"event": "summary", "address": 5, "requests": 2, "failed": 0}
        r = fap("g485", "scan", "--port", bus.paths[0], "--last", "6", "--timeout", "1",
                "--json")
        assert r.code == 0, r.err
        objs = _json(r.lines())
        assert [o["address"] for o in objs if o["event"] == "found"] == [2, 5]
        assert objs[-1] == {"event": "summary", "found": [2, 5], "tried": 6}
    r = fap("g485", "read", "--port", bus.paths[0], "--address", "1", "--register", "1",
            "--rs485", "kernel")
    # G485 runs on the C port layer: kernel RS-485 on a pty is a port error (ENOTTY)
    assert r.code == 3 and len(r.err.splitlines()) == 1, r.err
    assert r.err.startswith("fap: error: ") and "kernel RS-485" in r.err, r.err


def test_g485_sim_prints_ready_and_summary(fap, bus) -> None:
    sim = _start("g485", "sim", "--port", bus.paths[1], "--address", "3", "--json")
    try:
        assert json.loads(sim.stdout.readline())["event"] == "ready"
        r = fap("g485", "handshake", "--port", bus.paths[0], "--address", "3", "--json")
        assert r.code == 0 and "check" in json.loads(r.out)
    finally:
        lines = _stop(sim)
    summary = json.loads(lines[-1])
    assert summary["event"] == "summary" and summary["replies"] >= 1


def test_ports_lists_and_probes(fap, bus) -> None:
    r = fap("ports", "--device", bus.paths[0], "--json")
    assert r.code == 0
    rows = {o["device"]: o for o in _json(r.lines())}
    row = rows[bus.paths[0]]
    assert row["rs485"] == "no"            # a pty: TIOCGRS485 -> ENOTTY, through the C layer
    assert row["baud"] in (9600, 38400, 115200)
    r = fap("ports", "--device", bus.paths[0])
    assert "RS-485: no kernel support (ENOTTY)" in r.out
    r = fap("ports", "--device", "/nonexistent/tty", "--json")
    row = _json(r.lines())[-1]
    assert row["rs485"] == "unknown" and "No such file" in row["error"]


def test_vv_logs_wire_bytes_through_the_command(bus) -> None:
    from .conftest import run_proc

    frame = execasync.encode(2, b"\x0a\x0b", 0)
    with execasync.Slave(bus.paths[1], node=2, handler=lambda q: q.data, rs485=LINE).start():
        r = run_proc("exec", "master", "--port", bus.paths[0], *NONE, "--node", "2", "0a0b",
                     "--timeout", "2", "--retries", "0", "-vv")
    assert r.code == 0, r.err
    assert f"fap_py.wire.exec DEBUG {bus.paths[0]} tx ok {len(frame)} bytes: {frame.hex(' ')}" \
        in r.err
    assert f"fap_py.wire.exec DEBUG {bus.paths[0]} rx ok {len(frame)} bytes: {frame.hex(' ')}" \
        in r.err
    r = run_proc("exec", "master", "--port", bus.paths[0], *NONE, "--node", "2", "0a0b",
                 "--timeout", "0.01", "--retries", "0")
    assert "fap_py.wire" not in r.err          # not without -vv


def test_scan_progress_bar_on_a_terminal(bus, tmp_path) -> None:
    """Under a pty: a progress bar on stderr; with stdout redirected the found
    nodes still land in stdout, never in the bar's stream."""
    import os
    import pty
    import select

    out_file = tmp_path / "found.txt"
    with execasync.Slave(bus.paths[1], node=7, handler=lambda q: b"", rs485=LINE).start():
        master_fd, slave_fd = pty.openpty()
        with open(out_file, "w") as out:
            p = subprocess.Popen(fap_cmd("exec", "scan", "--port", bus.paths[0], *NONE,
                                         "--last", "12", "--timeout", "0.5"),
                                 stdin=slave_fd, stdout=out, stderr=slave_fd,
                                 env=dict(os.environ, COLUMNS="100", TERM="xterm"))
        os.close(slave_fd)
        screen = b""
        while True:
            r, _, _ = select.select([master_fd], [], [], 0.5)
            if r:
                try:
                    chunk = os.read(master_fd, 65536)
                except OSError:
                    break
                if not chunk:
                    break
                screen += chunk
            elif p.poll() is not None:
                break
        p.wait(30)
        os.close(master_fd)
    assert p.returncode == 0
    text = screen.decode(errors="replace")
    assert "exec node" in text and "/12" in text          # the bar: label and n/total
    found = out_file.read_text().splitlines()
    assert found[0] == "node 7 answers: (empty)" and found[-1] == "1 of 12 nodes answered: 7"
