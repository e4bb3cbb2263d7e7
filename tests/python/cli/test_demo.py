"""`fap demo` without a terminal (plain lines, summary) and under a pseudo-terminal
(a live view redrawn in place)."""
from __future__ import annotations

import json
import os
import pty
import re
import select
import signal
import subprocess
import time

from .conftest import fap_cmd, run_proc


def test_demo_without_a_terminal() -> None:
    r = run_proc("demo", "--duration", "1.5")
    assert r.code == 0, r.err
    assert r.err == ""
    out = r.out
    assert out.startswith("FAP demo: master + slaves 3, 7, 12 on a virtual RS-485 bus")
    for i in (3, 7, 12):
        assert f"slave {i} active (answered QUERY_ID)" in out
    # a loaded machine may catch a slave between a missed DATA_DONE and its next ID answer
    assert "summary after " in out and re.search(r"active slaves (?:[\d, ]+|none) \(of 3, 7, 12\)", out)
    rows = [line for line in out.splitlines() if re.match(r"^(master|slave \d+)\s+\d+(\s+\d+){8}$",
                                                         line)]
    assert len(rows) == 4
    assert re.search(r"goodput \d+ B/s \(\d+ DATA frames x 32 B\); wire capacity 11520 B/s", out)
    assert "unpaced bus: the ptys deliver faster than the baud" in out   # issue 33: said
    assert max(len(line) for line in out.splitlines()) < 120   # no line a terminal would wrap
    assert "\x1b[" not in out          # no terminal codes in a pipe


def test_demo_default_duration_without_a_terminal_is_short() -> None:
    t0 = time.monotonic()
    r = run_proc("demo", "--json", "--slaves", "1")
    assert r.code == 0, r.err
    summary = json.loads(r.out.splitlines()[-1])
    assert summary["event"] == "summary" and 2.5 <= summary["seconds"] <= 10
    assert time.monotonic() - t0 < 30


def test_demo_json_counters_are_the_engines() -> None:
    r = run_proc("demo", "--json", "--duration", "1", "--slaves", "2")
    assert r.code == 0, r.err
    objs = [json.loads(line) for line in r.out.splitlines()]
    assert objs[0]["event"] == "start" and objs[0]["slaves"] == [3, 7]
    summary = objs[-1]
    assert summary["event"] == "summary" and not summary["interrupted"]
    nodes = summary["nodes"]
    assert set(nodes) == {"master", "slave 3", "slave 7"}
    # fapx stats: what the master delivered is what the slaves sent (no faults)
    assert nodes["master"]["data_rx"] > 0
    assert nodes["master"]["data_rx"] <= nodes["slave 3"]["data_tx"] + nodes["slave 7"]["data_tx"]
    assert summary["wire_bytes"] == sum(n["bytes_tx"] for n in nodes.values())
    assert summary["data_frames"] == sum(n["data_rx"] for n in nodes.values())
    assert summary["capacity"] == 11520.0


def test_demo_faults_show_inactive_and_recovery() -> None:
    r = run_proc("demo", "--json", "--faults", "--duration", "6", "--slaves", "2")
    assert r.code == 0, r.err
    objs = [json.loads(line) for line in r.out.splitlines()]
    # structured events, no pre-formatted text (issue 25 defect 11)
    assert all("text" not in o for o in objs)
    events = [(o["event"], o.get("slave")) for o in objs if o["event"] not in ("status", "start")]
    silenced = events.index(("fault", 7))
    after = events[silenced:]
    assert ("slave_inactive", 7) in after, events
    assert ("slave_active", 7) in after[after.index(("slave_inactive", 7)):], events  # recovered
    assert ("fault_over", 7) in after, events
    assert all(isinstance(o["t"], float) for o in objs if o["event"].startswith("slave_"))


def _read_pty(fd: int, proc: subprocess.Popen, timeout: float) -> bytes:
    out = b""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        r, _, _ = select.select([fd], [], [], 0.2)
        if r:
            try:
                chunk = os.read(fd, 65536)
            except OSError:       # EIO: the child closed the terminal
                break
            if not chunk:
                break
            out += chunk
        elif proc.poll() is not None:
            break
    return out


def _pty_demo(*args: str, interrupt_after: float = 0.0):
    master, slave = pty.openpty()
    os.set_blocking(master, True)
    env = dict(os.environ, COLUMNS="110", LINES="40", TERM="xterm-256color")
    env.pop("NO_COLOR", None)
    proc = subprocess.Popen(fap_cmd("demo", *args), stdin=slave, stdout=slave, stderr=slave,
                            env=env, close_fds=True, start_new_session=True)
    os.close(slave)
    try:
        if interrupt_after:
            out = b""
            # wait for the first screen, then Ctrl-C as a terminal would send it
            while b"nodes (engine counters)" not in out:
                out += _read_pty(master, proc, 0.5)
                assert proc.poll() is None, out
            time.sleep(interrupt_after)   # let the live view run a little (not a sync)
            os.killpg(proc.pid, signal.SIGINT)
            out += _read_pty(master, proc, 30)
        else:
            out = _read_pty(master, proc, 60)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    return proc.returncode, out.decode(errors="replace")


def test_demo_live_view_under_a_pty() -> None:
    code, screen = _pty_demo("--duration", "2.5", "--slaves", "2")
    assert code == 0, screen
    # a live view: drawn many times in place (cursor moved up, lines erased)
    assert screen.count("nodes (engine counters)") >= 3, screen
    assert "\x1b[2K" in screen and re.search(r"\x1b\[\d*A", screen)
    for needle in ("recent messages", "events", "goodput", "slave 3", "slave 7", "polling",
                   "active", "summary after"):
        assert needle in screen, needle
    # the elapsed time advances between redraws
    times = [float(t) for t in re.findall(r"(\d+\.\d) / 2\.5 s", screen)]
    assert len(set(times)) >= 3 and times == sorted(times)


def test_demo_ctrl_c_ends_with_the_summary() -> None:
    code, screen = _pty_demo("--duration", "60", "--slaves", "1", interrupt_after=0.5)
    assert code == 130, screen
    assert "summary after " in screen and "(interrupted)" in screen
    assert "Traceback" not in screen
