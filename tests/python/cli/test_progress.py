"""Long runs show progress on a terminal and stay quiet without one (issue 25):
`fap bus` status line, `fap soak` and `python -m bench` progress bars; bench
without matplotlib skips its plots with a note."""
from __future__ import annotations

import json
import os
import pty
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, List, Optional, Tuple

import pytest

from .conftest import fap_cmd

ROOT = Path(__file__).resolve().parents[3]


def _with_tty_stderr(argv: List[str], *, until: Optional[Callable[[bytes], bool]] = None,
                     timeout: float = 120, **kw) -> Tuple[subprocess.Popen, bytes, bytes]:
    """Run ``argv`` with stderr on a pseudo-terminal (stdout a pipe) and read
    the terminal until the process ends; once ``until(seen)`` holds it gets a
    SIGTERM. Returns the ended process, its stdout and the terminal's bytes."""
    master, slave = pty.openpty()
    env = dict(os.environ, TERM="xterm", COLUMNS="100")
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL,
                         env=env, **kw)
    os.close(slave)
    seen = b""
    end = time.monotonic() + timeout
    try:
        while time.monotonic() < end:
            if until is not None and until(seen):
                p.send_signal(signal.SIGTERM)
                until = None
            r, _, _ = select.select([master], [], [], 0.2)
            if r:
                try:
                    chunk = os.read(master, 65536)
                except OSError:       # EIO: the process closed its terminal
                    chunk = b""
                if not chunk and p.poll() is not None:
                    break
                seen += chunk
            elif p.poll() is not None:
                break
        if p.poll() is None:          # the deadline, not the process, ended the loop: end it,
            p.terminate()             # so that reading its stdout cannot block the test
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        out = p.stdout.read() if p.stdout else b""
        p.wait(timeout=30)
        return p, out, seen
    finally:
        os.close(master)


def test_bus_status_on_a_terminal(tmp_path: Path) -> None:
    p, out, seen = _with_tty_stderr(fap_cmd("bus", "--ports", "2", "--link-dir", str(tmp_path)),
                                    until=lambda s: s.count(b"bus: in ") >= 2, timeout=30)
    assert seen.count(b"bus: in ") >= 2, seen    # redrawn twice a second
    assert b"errors: collisions 0" in seen and b"(per-port rows with --capture)" in seen
    assert p.returncode == 0 and b"stats bytes_in=" in out


def test_bus_status_per_port_from_the_capture(tmp_path: Path) -> None:
    links, cap = tmp_path / "bus", tmp_path / "bus.cap"
    sent = []

    def until(seen: bytes) -> bool:
        if b"bus: in " in seen and not sent:       # the bus is up: one node writes 1000 bytes
            fd = os.open(links / "port0", os.O_RDWR | os.O_NOCTTY)
            os.write(fd, bytes(1000))
            sent.append(fd)
        return b"1,000" in seen                    # port0's byte total, from the capture

    argv = fap_cmd("bus", "--ports", "2", "--link-dir", str(links), "--capture", str(cap))
    try:
        p, out, seen = _with_tty_stderr(argv, until=until, timeout=30)
    finally:
        for fd in sent:
            os.close(fd)
    assert b"1,000" in seen, seen
    assert b"tx/s" in seen and b"port0" in seen and b"port1" in seen
    assert p.returncode == 0 and b"bytes_in=1000 " in out


def test_soak_progress_on_a_terminal_only() -> None:
    argv = fap_cmd("soak", "--protocol", "mikroc", "--seconds", "1", "--check8-seconds", "0.3",
                   "--slaves", "1", "--json")
    p, out, seen = _with_tty_stderr(argv)
    assert p.returncode in (0, 1), seen
    assert b"soak mikroc" in seen, seen                      # the rich bar's label
    assert json.loads(out)["protocol"] == "mikroc"
    q = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert "soak mikroc" not in q.stderr and json.loads(q.stdout)["protocol"] == "mikroc"


def _build_dir() -> Optional[Path]:
    for d in (Path.cwd().parent, Path.cwd(), ROOT / "build"):   # meson test runs in build/tests
        if (d / "build.ninja").exists() and (d / "bench" / "wire").is_dir():
            return d
    return None


def test_bench_without_matplotlib_skips_the_plots(tmp_path: Path) -> None:
    """A tiny run (one cell, 0.1 s: seconds, not the 100 s of a --quick run)
    with matplotlib and pytest hidden: the plots are skipped and said so, the
    bench needs nothing of the tests, and perf's window notes stay quiet."""
    build = _build_dir()
    if build is None:
        if os.environ.get("CI"):
            pytest.fail("no meson build directory with bench/ for python -m bench")
        pytest.skip("no meson build directory")
    # matplotlib and pytest hidden (None in sys.modules), the bench run as `python -m bench`
    code = ("import runpy, sys; sys.modules['matplotlib'] = None; sys.modules['pytest'] = None; "
            "runpy.run_module('bench', run_name='__main__', alter_sys=True)")
    argv = [sys.executable, "-c", code, "--quick", "--only", "bare", "--sections", "paced",
            "--seconds", "0.1", "--build-dir", str(build), "--out", str(tmp_path / "out")]
    t0 = time.monotonic()
    p, out, seen = _with_tty_stderr(argv, cwd=ROOT, timeout=40)
    took = time.monotonic() - t0
    text = seen.decode(errors="replace")
    assert p.returncode == 0, text
    assert "bench: matplotlib missing, plots skipped" in text
    assert "Traceback" not in text and "ModuleNotFoundError" not in text
    assert "paced 115200: bare" in text        # the rich bar's description, on the terminal
    assert "Events disabled" not in text and "Events enabled" not in text   # perf's own notes
    # the Python peers are not run by --quick: said so, never called "missing"
    assert "--quick: not run: minimalmodbus, pymodbus, dynamixel" in text
    assert "missing, skipped" not in text
    assert b"(no plots: matplotlib missing)" in out
    made = {f.name for f in (tmp_path / "out").iterdir()}
    assert {"results.json", "table.md"} <= made and not any(n.endswith(".png") for n in made)
    res = json.loads((tmp_path / "out" / "results.json").read_text())
    assert list(res["paced"]["115200"]) == ["bare"] and res["missing"] == {}
    assert res["skipped"]["pymodbus"].startswith("not run in --quick")
    assert took < 30, f"the tiny bench run took {took:.1f} s"
