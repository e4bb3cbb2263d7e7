"""Hostile roots: unreadable files, symlink loops, huge files, fifos and binary junk
give findings or skips, never a traceback, and the run stays bounded."""
from __future__ import annotations

import os
import time

from doctor_helpers import doctor

from fap_py.doctor import Finding
from fap_py.doctor import _registry as registry
from fap_py.doctor._context import READ_MAX, Context


def test_hostile_root(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00", latency=1)
    junk = bytes(range(256)) * 64 + b"\xff\xfe\x00console=\x00ttyUSB0"
    for path in ("/proc/cmdline", "/proc/locks", "/proc/1/cgroup", "/var/log/kern.log",
                 "/boot/firmware/config.txt", "/proc/self/status", "/run/lock/LCK..ttyUSB0",
                 "/etc/systemd/system/fap-x.service", "/proc/device-tree/model"):
        tree.write(path, junk)
    tree.write("/boot/firmware/config.txt", b"[pi5]\ninclude config.txt\ninclude ../../../../etc/shadow\n" + junk)
    tree.write("/proc/device-tree/model", b"Raspberry Pi 5\x00\xff\xfe")
    # symlink loops: a unit, the serial0 link, a process fd, a udev rules dir
    tree.link("/etc/systemd/system/loop.service", "/etc/systemd/system/loop.service")
    tree.link("/dev/serial0", "serial1")
    tree.link("/dev/serial1", "serial0")
    tree.process(9, "x", ["x"], {1: "/proc/9/fd/1", 2: "/dev/ttyUSB0/../ttyUSB0"})
    tree.link("/etc/udev/rules.d", "/etc/udev/rules.d")
    # a huge sparse /etc/passwd and group, read only READ_MAX bytes
    with open(tree.p("/etc/group"), "r+b") as f:
        f.truncate(1 << 30)
    # a fifo where a file should be: never opened for a blocking read
    tree.p("/proc/9/comm").unlink()
    os.mkfifo(tree.p("/proc/9/comm"))
    # an unreadable file (root reads it anyway; either way no traceback)
    tree.write("/lib/systemd/system/ModemManager.service", "[Service]\n", mode=0)
    # a directory where a file should be, a dangling link
    tree.p("/etc/passwd").unlink()
    tree.p("/etc/passwd").mkdir()
    tree.link("/proc/cmdline", "/nonexistent")
    t0 = time.monotonic()
    code, fs, err = doctor(fap_main, "/dev/ttyUSB0", "--root", str(tree.root))
    assert time.monotonic() - t0 < 10
    assert code in (0, 4, 5) and "Traceback" not in err, err
    assert {f["id"] for f in fs} >= {"port.holder", "perm.group", "console.cmdline"}
    code, fs, err = doctor(fap_main, "/dev/serial0", "--root", str(tree.root), "--user", "pi")
    assert code in (0, 4, 5) and "Traceback" not in err
    assert next(f for f in fs if f["id"] == "port.exists")["severity"] == "error"   # a loop
    # plain text output too
    code, out, err = fap_main("doctor", "--root", str(tree.root))
    assert code in (0, 4, 5) and "Traceback" not in err and out


def test_reads_are_bounded(tree):
    big = tree.write("/etc/hosts", "x" * (READ_MAX * 3))
    assert big.stat().st_size == READ_MAX * 3
    ctx = Context(root=str(tree.root))
    assert len(ctx.read("/etc/hosts")) == READ_MAX
    tail = ctx.read("/etc/hosts", 10, tail=True)
    assert tail == "x" * 10
    assert ctx.read("/etc/../etc/../../../../etc/hosts") is not None     # .. stays beneath root
    tree.link("/etc/escape", "../../../../../../../etc/hostname")
    assert ctx.canonical("/etc/escape") == "/etc/hostname"
    assert ctx.host("/etc/escape").startswith(str(tree.root))
    assert ctx.canonical("bad\0path") is None


def test_a_failing_check_is_a_skip(tree, monkeypatch):
    def boom(ctx):
        raise RuntimeError("hostile")
        yield  # pragma: no cover

    registry.all_checks()
    c = registry._CHECKS["brltty"]
    monkeypatch.setitem(registry._CHECKS, "brltty", registry.Check(c.id, c.title, boom, c.order))
    fs = registry.run(Context(root=str(tree.root)), only=["brltty"])
    assert fs == [Finding("brltty", "info", "check skipped: RuntimeError: hostile")]


def test_finding_refuses_a_bad_severity():
    import pytest

    from fap_py.errors import InvalidValueError
    with pytest.raises(InvalidValueError):
        Finding("x", "fatal", "no")


def test_check_ids_are_unique_and_many():
    import pytest

    from fap_py.errors import InvalidValueError
    checks = registry.all_checks()
    assert len(checks) >= 15 and len({c.id for c in checks}) == len(checks)
    with pytest.raises(InvalidValueError):
        registry.check(checks[0].id, "again")(lambda ctx: [])


def test_docs_list_every_check():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[3] / "docs" / "doctor.md").read_text()
    for c in registry.all_checks():
        assert f"| `{c.id}` |" in doc, c.id
    assert "| `listen.bus` |" in doc


def test_fifo_or_huge_file_in_sysfs_is_not_read(fap_main, tree):
    """`fap ports`' sysfs reader opens files whole and blocking: a copied /sys with a
    fifo or a huge file there is reported, not read (no hang)."""
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00", latency=1)
    lt = next(tree.p("/sys/devices").rglob("latency_timer"))
    lt.unlink()
    os.mkfifo(lt)
    t0 = time.monotonic()
    code, fs, err = doctor(fap_main, "--root", str(tree.root), "--user", "pi")
    assert time.monotonic() - t0 < 10 and code == 4
    f = fs[0]
    assert f["id"] == "port.exists" and "latency_timer: not a small regular file" in f["evidence"][0]
    lt.unlink()
    with open(lt, "wb") as fh:
        fh.truncate(READ_MAX + 1)
    code, fs, err = doctor(fap_main, "--root", str(tree.root), "--user", "pi")
    assert fs[0]["id"] == "port.exists" and fs[0]["severity"] == "warning"
