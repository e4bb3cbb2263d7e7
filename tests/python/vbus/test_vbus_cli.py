"""``fap bus``: the CLI runs a bus until SIGINT and reports its counters."""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path

from vbus_helpers import WAIT_S, open_port, read_exact, write_all

from fap_py.vbus import read_capture


def _start(args: list, cwd: Path) -> tuple:
    """Start ``fap bus`` (cwd outside the source tree: the installed package
    runs); returns the process and a queue of its stdout lines."""
    proc = subprocess.Popen([sys.executable, "-m", "fap_py", "bus", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)
    lines: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in proc.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return proc, lines


def _wait_ready(proc: subprocess.Popen, lines: queue.Queue) -> list:
    """The printed port paths, once ``ready`` came (deadline 10 s)."""
    paths = []
    while True:
        line = lines.get(timeout=10)
        assert line is not None, proc.stderr.read()
        if line.startswith("ready"):
            return paths
        paths.append(line.split()[1])


def _stop(proc: subprocess.Popen, lines: queue.Queue, sig: int) -> str:
    proc.send_signal(sig)
    proc.wait(timeout=10)
    out = []
    while (line := lines.get(timeout=10)) is not None:
        out.append(line)
    return "".join(out)


def test_fap_bus_runs_until_sigint(tmp_path: Path) -> None:
    links = tmp_path / "links"
    cap = tmp_path / "cap.txt"
    proc, lines = _start(["--ports", "3", "--baud", "38400", "--link-dir", str(links),
                          "--capture", str(cap), "--seed", "7"], tmp_path)
    try:
        paths = _wait_ready(proc, lines)
        assert paths == [str(links / f"port{i}") for i in range(3)]
        fds = [open_port(p) for p in paths]
        try:
            write_all(fds[2], b"\x01\x02\x03\x04")
            assert read_exact(fds[0], 4, WAIT_S) == b"\x01\x02\x03\x04"
            assert read_exact(fds[1], 4, WAIT_S) == b"\x01\x02\x03\x04"
        finally:
            for fd in fds:
                os.close(fd)
        out = _stop(proc, lines, signal.SIGINT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, proc.stderr.read()
    assert "bytes_in=4 bytes_out=8 collisions=0" in out
    assert not links.exists()
    assert read_capture(cap).data_from(2) == b"\x01\x02\x03\x04"


def test_fap_bus_sigterm_and_bad_arguments(tmp_path: Path) -> None:
    bad = subprocess.run([sys.executable, "-m", "fap_py", "bus", "--ports", "1"],
                         capture_output=True, text=True, timeout=30, cwd=tmp_path)
    assert bad.returncode == 1
    assert "fap: error" in bad.stderr and "ports" in bad.stderr
    proc, lines = _start(["--ports", "2", "--ber", "0.5", "--drop-rate", "0.1"], tmp_path)
    try:
        assert len(_wait_ready(proc, lines)) == 2
        out = _stop(proc, lines, signal.SIGTERM)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, proc.stderr.read()
    assert out.strip().splitlines()[-1].startswith("stats bytes_in=0")
