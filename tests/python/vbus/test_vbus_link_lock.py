"""Issue 33 item 1: one bus per link directory. A second bus (``fap bus``
or :class:`VirtualBus`) on a ``link_dir`` a live bus holds is refused with
one line naming the holder's pid (exit 3) and leaves the first bus's links
alone; the lock of a process that died (SIGKILL) is taken over."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from test_vbus_cli import _start, _stop, _wait_ready
from vbus_helpers import open_port, read_exact, write_all

from fap_py.errors import PortBusyError
from fap_py.vbus import LINK_DIR_LOCK, LinkDirBusyError, VirtualBus


def _fap_bus(args: list, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fap_py", "bus", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=30)


def test_second_fap_bus_on_the_same_link_dir_is_refused(tmp_path: Path) -> None:
    links = tmp_path / "links"
    proc, lines = _start(["--ports", "2", "--link-dir", str(links)], tmp_path)
    try:
        paths = _wait_ready(proc, lines)
        targets = [os.readlink(p) for p in paths]
        assert (links / LINK_DIR_LOCK).read_text().strip() == str(proc.pid)
        second = _fap_bus(["--ports", "2", "--link-dir", str(links)], tmp_path)
        assert second.returncode == 3, second
        assert second.stderr.strip() == (
            f"fap: error: {links}: --link-dir: another fap bus (pid {proc.pid}) is running "
            "on it; stop it or use another directory")
        assert "ready" not in second.stdout
        # the first bus's links are untouched and still carry bytes
        assert [os.readlink(p) for p in paths] == targets
        a, b = open_port(paths[0]), open_port(paths[1])
        try:
            write_all(a, b"still here")
            assert read_exact(b, 10) == b"still here"
        finally:
            os.close(a)
            os.close(b)
    finally:
        _stop(proc, lines, signal.SIGINT)
    assert proc.returncode == 0
    assert not links.exists()     # made by the bus: removed with its lock file and links


def test_stale_lock_of_a_killed_bus_is_taken_over(tmp_path: Path) -> None:
    links = tmp_path / "links"
    proc, lines = _start(["--ports", "2", "--link-dir", str(links)], tmp_path)
    _wait_ready(proc, lines)
    proc.kill()                   # no cleanup: the lock file and links stay behind
    proc.wait(timeout=10)
    assert (links / LINK_DIR_LOCK).read_text().strip() == str(proc.pid)
    proc2, lines2 = _start(["--ports", "2", "--link-dir", str(links)], tmp_path)
    try:
        paths = _wait_ready(proc2, lines2)
        assert (links / LINK_DIR_LOCK).read_text().strip() == str(proc2.pid)
        assert all(os.path.exists(p) for p in paths)
    finally:
        _stop(proc2, lines2, signal.SIGTERM)
    assert proc2.returncode == 0
    assert not (links / LINK_DIR_LOCK).exists()
    assert links.exists()         # it existed before this bus: left in place, empty
    assert list(links.iterdir()) == []


def test_api_second_bus_on_a_link_dir_is_refused(tmp_path: Path) -> None:
    links = tmp_path / "links"
    with VirtualBus(ports=2, link_dir=links) as bus:
        before = [os.readlink(p) for p in bus.paths]
        with pytest.raises(LinkDirBusyError) as info:
            VirtualBus(ports=2, link_dir=links)
        assert isinstance(info.value, PortBusyError) and info.value.pid == os.getpid()
        assert f"pid {os.getpid()}" in str(info.value) and str(links) in str(info.value)
        assert [os.readlink(p) for p in bus.paths] == before
    with VirtualBus(ports=2, link_dir=links) as bus:   # released at close
        assert len(bus.paths) == 2
    assert not links.exists()
