"""``fap sim`` as a process: examples start and answer the CLI masters; faults switched
through ``--control`` and ``fap sim fault``; ``fap sim status``; hostile control input."""
from __future__ import annotations

import json
import os
import socket

import pytest

from .conftest import EXAMPLES, cli, run


def test_site_example_answers_the_cli_masters(sim_process, control):
    sim = sim_process(os.path.join(EXAMPLES, "site.toml"), "--control", control)
    names = [b["name"] for b in sim.ready["buses"]]
    assert names == ["plc", "relays", "sensors"]
    r = cli("exec", "master", "--port", sim.port(0), "--node", "5", "--timeout", "0.5", "--json", "0102")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[0])["data"] == "0102"
    r = cli("exec", "master", "--port", sim.port(0), "--node", "12", "--timeout", "0.5", "--json", "00")
    assert r.returncode == 0 and json.loads(r.stdout.splitlines()[0])["data"] == "0064"   # counter 100
    r = cli("mikroc", "master", "--port", sim.port(1), "--address", "7", "--json", "0105")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[0]) == {"event": "reply", "address": 7, "data": "aa"}
    r = cli("g485", "read", "--port", sim.port(2), "--address", "9", "--register", "12", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.splitlines()[0])["values"] == [42]
    sim.stop()


def test_fault_cli_reaches_fap_exec(sim_process, control):
    sim = sim_process(os.path.join(EXAMPLES, "site.toml"), "--control", control)
    # a fault from the CLI reaches `fap exec` (exit 1, its no-reply line), and is counted
    r = cli("sim", "fault", "add", "no_reply", "--node", "5", "--bus", "plc", "--control", control, "--json")
    assert r.returncode == 0, r.stderr
    fid = json.loads(r.stdout)["fault"]["id"]
    r = cli("exec", "master", "--port", sim.port(0), "--node", "5", "--timeout", "0.2", "--retries", "0", "01")
    assert r.returncode == 1 and "no reply" in r.stdout and "failed" in r.stderr
    r = cli("sim", "fault", "list", "--control", control)
    assert f"#{fid} no_reply bus plc node 5 p=1 applied 1" in r.stdout
    r = cli("sim", "status", "--control", control, "--json")
    st = json.loads(r.stdout)
    node5 = [n for n in st["buses"][0]["nodes"] if n["address"] == 5][0]
    assert node5["faults"] == {"no_reply": 1} and st["faults_applied"]["no_reply"] == 1
    r = cli("sim", "fault", "remove", str(fid), "--control", control)
    assert r.returncode == 0 and f"removed #{fid}" in r.stdout
    r = cli("exec", "master", "--port", sim.port(0), "--node", "5", "--timeout", "0.5", "01")
    assert r.returncode == 0, r.stderr
    r = cli("sim", "status", "--control", control)
    assert "node 5: 2 requests, 1 replies, faults no_reply 1" in r.stdout
    final = sim.stop()
    assert final["event"] == "stopped" and final["faults_applied"]["no_reply"] == 1


def test_scheduled_and_byte_level_faults_from_the_cli(sim_process, control):
    sim = sim_process(os.path.join(EXAMPLES, "site.toml"), "--control", control)
    r = cli("sim", "fault", "add", "split", "--ms", "10", "--node", "5", "--bus", "plc",
            "--at", "3600", "--for", "60", "--every", "120", "--control", control, "--json")
    assert r.returncode == 0, r.stderr
    f = json.loads(r.stdout)["fault"]
    assert (f["ms"], f["at"], f["for"], f["every"], f["active"]) == (10, 3600, 60, 120, False)
    r = cli("sim", "fault", "add", "bit_errors", "--rate", "0.5", "--node", "7", "--control", control)
    assert r.returncode == 0 and "bit_errors rate 0.5" in r.stdout
    r = cli("sim", "fault", "list", "--control", control)
    assert "split ms 10 bus plc node 5 p=1 at 3600 s for 60 s every 120 s (off)" in r.stdout
    # not yet in force: the split fault leaves node 5 alone
    r = cli("exec", "master", "--port", sim.port(0), "--node", "5", "--timeout", "0.5", "01")
    assert r.returncode == 0, r.stderr
    for bad, msg in ((["off", "--ms", "4"], "ms is not a parameter of off"),
                     (["off", "--every", "2"], "every needs for"),
                     (["error_reply", "--word", "7", "--bus", "plc"], "not implemented")):
        r = cli("sim", "fault", "add", *bad, "--control", control)
        assert r.returncode == 2 and msg in r.stderr, r.stderr
    sim.stop()


def test_control_cli_errors(sim_process, control):
    sim = sim_process(os.path.join(EXAMPLES, "fap_bus.toml"), "--control", control)
    r = cli("sim", "fault", "add", "bad_crc", "--control", control)
    assert r.returncode == 2 and "not implemented" in r.stderr
    r = cli("sim", "fault", "remove", "77", "--control", control)
    assert r.returncode == 2 and "no fault has id 77" in r.stderr
    r = cli("sim", "fault", "add", "late_reply", "--control", control)
    assert r.returncode == 2 and "--ms" in r.stderr
    r = cli("sim", "status", "--control", "unix:/nonexistent/x.sock")
    assert r.returncode == 3 and "is `fap sim --control" in r.stderr
    r = cli("sim", "status", "--control", "tcp:1.2.3.4")
    assert r.returncode == 2 and "unix:PATH" in r.stderr
    sim.stop()


def _ask(sock: socket.socket, data: bytes) -> dict:
    sock.sendall(data)
    buf = b""
    while not buf.endswith(b"\n"):
        chunk = sock.recv(65536)
        if not chunk:
            break
        buf += chunk
    return json.loads(buf.splitlines()[0]) if buf else {}


def test_hostile_control_input_does_not_stop_the_sim(sim_process, control):
    sim = sim_process(os.path.join(EXAMPLES, "faults.json"), "--control", control)
    path = control[5:]
    with socket.socket(socket.AF_UNIX) as s:
        s.settimeout(5)
        s.connect(path)
        assert _ask(s, b"\xff\xfe garbage\n") == {"ok": False, "error": "not a JSON line"}
        assert _ask(s, b"[1,2]\n")["error"] == "a request is a JSON object"
        assert "unknown cmd" in _ask(s, b'{"cmd": "reboot"}\n')["error"]
        assert "unknown key" in _ask(s, b'{"cmd": "fault.add", "kind": "off", "evil": 1}\n')["error"]
        assert "probability" in _ask(s, b'{"cmd": "fault.add", "kind": "off", "probability": 7}\n')["error"]
        assert "node" in _ask(s, b'{"cmd": "fault.add", "kind": "off", "node": [1]}\n')["error"]
        assert "no fault has id" in _ask(s, b'{"cmd": "fault.remove", "id": {"a": 1}}\n')["error"]
        assert _ask(s, b'[' * 60000 + b'\n')["ok"] is False
        ans = _ask(s, b'{"cmd": "fault.list"}\n')     # the same connection still works
        assert ans["ok"] and [f["kind"] for f in ans["faults"]] == ["late_reply", "no_reply"]
    with socket.socket(socket.AF_UNIX) as s:
        s.settimeout(5)
        s.connect(path)
        ans = _ask(s, b"x" * (200 * 1024))          # no newline, oversized: refused, closed
        assert ans["ok"] is False and "longer than" in ans["error"]
    r = cli("exec", "master", "--port", sim.port(), "--node", "200", "--timeout", "0.5", "--json", "00")
    assert r.returncode == 0, r.stderr               # the sim still answers
    r = cli("sim", "status", "--control", control, "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["ok"] is True
    sim.stop()


def test_fap_example_answers_the_fap_master(sim_process):
    from fap_py import fap

    sim = sim_process(os.path.join(EXAMPLES, "fap_bus.toml"))
    with fap.Master(sim.port(), 115200, slaves=[3, 4, 5], id_cycle=0.05) as m:
        m.wait_active([3, 4, 5], timeout=5)
        msg = m.recv(timeout=5)
        assert msg.source == 3 and len(msg.data) == 2
    sim.stop()


def test_faults_example_static_faults(sim_process):
    from fap_py import execasync

    sim = sim_process(os.path.join(EXAMPLES, "faults.json"))
    with execasync.Master(sim.port(), 115200, timeout=0.02, retries=0) as m:
        assert len(m.transact(1, b"")) == 2          # a random value, 2 bytes
        with pytest.raises(execasync.NoReplyError):   # node 3: 50 ms late, after 20 ms timeout
            m.transact(3, b"")
        m.set_timeout(1.0)
        assert len(m.transact(3, b"")) == 2
    st = sim.stop()
    assert st["faults_applied"]["late_reply"] == 2


def test_run_errors(tmp_path):
    r = run("sim")
    assert r.returncode == 2 and "needs CONFIG" in r.stderr
    r = cli("sim", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and "missing.toml: cannot read" in r.stderr
    r = cli("sim", os.path.join(EXAMPLES, "site.toml"), "--port", "/dev/null")
    assert r.returncode == 2 and "one bus" in r.stderr
