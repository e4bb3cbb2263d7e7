#!/usr/bin/env python3
"""Boot the test initramfs in qemu-system-aarch64, drive it, judge it.

The guest's console (virtio-console hvc0) is QEMU's stdio; its PL011
(/dev/ttyAMA0) is a host pty. QEMU starts paused (-S): the pty is opened
(raw, so the host tty never echoes the guest's bytes back) before ``cont``.
Results: the guest's RESULT lines, plus the host's verdicts on the TRACE
checks from QEMU's ``pl011_write`` trace (the control register's RTS bit
around each check's payload in the data register). Exit status 0 only if
every check passed.
"""
from __future__ import annotations

import argparse
import os
import re
import select
import socket
import stat
import subprocess
import sys
import termios
import threading
import time
import tty
from pathlib import Path
from typing import Callable

CR_RTS = 0x800          # PL011 UARTCR.RTS: the complement of the nUARTRTS pin
REG_DR, REG_CR = 0x000, 0x030
GPIO_LINE = 1           # the PL061 line the GPIO checks use as DE (rs485_checks.c)
GPIO_OUT = 0x10000      # parse_trace's pseudo-offset of a PL061 output: + line
#: the whole guest run's bound: it takes 7-10 s here (TCG), but a CI run once took the
#: PL011 guest past 80 s with nothing else running (not reproduced since); a hang still
#: ends here. Each guest line is printed with its time, so a slow stretch shows where.
BOOT_TIMEOUT_S = 300


def cpio_newc(files: list[tuple[str, int, bytes, int]]) -> bytes:
    """A newc archive of (name, mode, data, rdev) entries."""
    out = bytearray()
    for ino, (name, mode, data, rdev) in enumerate(files + [("TRAILER!!!", 0, b"", 0)], 1):
        nb = name.encode() + b"\0"
        hdr = "070701" + "".join(f"{v:08x}" for v in (
            ino, mode, 0, 0, 1, 0, len(data), 0, 0, os.major(rdev), os.minor(rdev), len(nb), 0))
        out += hdr.encode() + nb
        out += b"\0" * (-len(out) % 4) + data
        out += b"\0" * (-len(out) % 4)
    return bytes(out)


def build_initramfs(root: Path, dest: Path) -> None:
    files = [("bin", stat.S_IFDIR | 0o755, b"", 0), ("dev", stat.S_IFDIR | 0o755, b"", 0),
             ("proc", stat.S_IFDIR | 0o755, b"", 0), ("sys", stat.S_IFDIR | 0o755, b"", 0),
             ("dev/console", stat.S_IFCHR | 0o600, b"", os.makedev(5, 1))]
    for p in sorted(root.iterdir()):
        if p.is_file():
            name = "bin/busybox" if p.name == "busybox" else p.name
            files.append((name, stat.S_IFREG | 0o755, p.read_bytes(), 0))
    data = cpio_newc(files)
    init = next(f for f in files if f[0] == "init")
    assert init[2].startswith(b"#!"), "init must be a script"
    dest.write_bytes(data)


def parse_trace(path: Path) -> list[tuple[float, int, int]]:
    """(host time s, register offset, value) of every pl011_write, and of
    every PL061 output change as (time, GPIO_OUT + line, level), in order."""
    rx = re.compile(r"@(\d+)\.(\d+):pl011_write addr 0x([0-9a-f]+) value 0x([0-9a-f]+)")
    gx = re.compile(r"@(\d+)\.(\d+):pl061_set_output \S+ setting output (\d+) to (\d+)")
    out = []
    for line in path.read_text(errors="replace").splitlines():
        m = rx.search(line)
        if m:
            out.append((int(m[1]) + int(m[2]) / 1e6, int(m[3], 16), int(m[4], 16)))
        m = gx.search(line)
        if m:
            out.append((int(m[1]) + int(m[2]) / 1e6, GPIO_OUT + int(m[3]), int(m[4]) != 0))
    return out


def judge_trace(name: str, fields: dict[str, str], writes: list[tuple[float, int, int]]) -> list[tuple[str, bool, str]]:
    """The pin around one check's payload: level while sending, the delays,
    the receive level while idle after the open."""
    payload = bytes.fromhex(fields["payload"])
    high = int(fields["high"]) == 1
    before, after = int(fields["before_ms"]), int(fields["after_ms"])
    dr = [(i, t, v) for i, (t, a, v) in enumerate(writes) if a == REG_DR]
    start = None
    for k in range(len(dr) - len(payload) + 1):
        if all(dr[k + j][2] & 0xFF == payload[j] for j in range(len(payload))):
            start = k
    if start is None:
        return [(f"{name}_trace_found", False, "payload not in the pl011_write trace")]
    i_first, t_first = dr[start][0], dr[start][1]
    i_last, t_last = dr[start + len(payload) - 1][0], dr[start + len(payload) - 1][1]
    if fields["mode"] == "gpio":   # the DE pin is a PL061 line: its level as traced
        crs = [(i, t, bool(v)) for i, (t, a, v) in enumerate(writes) if a == GPIO_OUT + GPIO_LINE]
    else:
        crs = [(i, t, not (v & CR_RTS)) for i, (t, a, v) in enumerate(writes) if a == REG_CR]

    def pin_at(idx: int) -> bool | None:
        level = None
        for i, _, pin in crs:
            if i >= idx:
                break
            level = pin
        return level

    # Edges: the last CR write before the first byte that brought the pin to
    # its level while sending; the first CR write after the last byte that
    # changed it back.
    during = pin_at(i_first)
    t_assert = None
    prev = None
    for i, t, pin in crs:
        if i > i_first:
            break
        if prev is not None and pin != prev and pin == during:
            t_assert = t
        prev = pin
    t_release, rel_level = None, None
    for i, t, pin in crs:
        if i > i_last and pin != during:
            t_release, rel_level = t, pin
            break
    idle_t = (t_assert if t_assert is not None else t_first) - 0.100
    idle_level = None
    for _i, t, pin in crs:
        if t > idle_t:
            break
        idle_level = pin
    lvl = {True: "high", False: "low", None: "?"}
    edges, prev = [], None
    for _i, t, pin in crs:   # pin changes from 60 ms before the first byte on
        if prev is not None and pin != prev and t_first - 0.060 - before / 1e3 < t < t_last + 0.060 + after / 1e3:
            edges.append(f"{lvl[pin]}@{(t - t_first) * 1e3:+.1f}ms")
        prev = pin
    timeline = " ".join(edges) + f" (bytes at 0..{(t_last - t_first) * 1e3:+.1f}ms)"
    res = []
    res.append((f"{name}_pin_while_sending", during == high,
                f"wanted {lvl[high]}, pin {lvl[during]} for {len(payload)} bytes; RTS pin edges {timeline}"))
    db = (t_first - t_assert) * 1e3 if t_assert is not None else None
    da = (t_release - t_last) * 1e3 if t_release is not None else None
    res.append((f"{name}_delay_before", db is not None and before * 0.9 <= db <= before + 40,
                f"configured {before} ms, measured {db if db is None else round(db, 2)} ms"))
    res.append((f"{name}_delay_after", da is not None and after * 0.9 <= da <= after + 40
                and rel_level == (not high),
                f"configured {after} ms, measured {da if da is None else round(da, 2)} ms, "
                f"then pin {lvl[rel_level]}"))
    res.append((f"{name}_receive_level_after_open", idle_level == (not high),
                f"idle 100 ms before sending: pin {lvl[idle_level]}, receive level {lvl[not high]}"))
    return res


def start_qemu(cmd: list[str], work: Path, mon: Path, trace: Path
               ) -> tuple[subprocess.Popen[bytes], Callable[[bytes], str]] | None:
    """Start QEMU paused (``-S``) with the console on virtio-console (its
    stdio: cmd names the virtio-serial bus), the monitor on ``mon`` and the
    trace log in ``trace``, and connect to the monitor: (process,
    monitor(command) -> answer), or None after printing why. The monitor
    connects to us (QEMU as the client): no waiting for a socket to appear."""
    cmd = cmd + ["-chardev", "stdio,id=con,signal=off", "-device", "virtconsole,chardev=con",
                 "-monitor", f"unix:{mon}", "-D", str(trace), "-msg", "timestamp=on", "-S"]
    listener = socket.socket(socket.AF_UNIX)
    listener.bind(str(mon))
    listener.listen(1)
    listener.settimeout(15)
    qerr = open(work / "qemu.stderr", "wb")
    q = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=qerr)
    try:
        ms, _ = listener.accept()
    except socket.timeout:
        q.kill()
        print("FAIL: QEMU's monitor never connected:", (work / "qemu.stderr").read_text(),
              file=sys.stderr)
        return None
    ms.settimeout(15)

    def monitor(command: bytes) -> str:
        out = b""
        ms.sendall(command + b"\n")
        while not out.endswith(b"(qemu) "):   # the prompt ends every answer
            out += ms.recv(4096)
        return out.decode(errors="replace")
    banner = b""
    while not banner.endswith(b"(qemu) "):
        banner += ms.recv(4096)
    return q, monitor


def suite_setup(description: str, *extra: tuple[str, str]
                ) -> tuple[argparse.Namespace, Path, Path, Path]:
    """The runners' common command line (--kernel --root --work --slave,
    plus (option, default) pairs), a fresh work directory and the
    initramfs: (args, initrd, trace log, monitor socket)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--kernel", required=True, type=Path)
    ap.add_argument("--root", required=True, type=Path, help="files of the initramfs")
    ap.add_argument("--work", required=True, type=Path)
    ap.add_argument("--slave", required=True, type=Path, help="host fap_slave binary")
    for opt, default in extra:
        ap.add_argument(opt, default=default)
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    initrd, trace, mon = a.work / "initrd.cpio", a.work / "trace.log", a.work / "monitor.sock"
    for p in (trace, mon):
        p.unlink(missing_ok=True)
    build_initramfs(a.root, initrd)
    return a, initrd, trace, mon


def report(suite: str, results: list[tuple[str, bool, str]], elapsed: float) -> int:
    """Print one PASS/FAIL line per check and the tally: the exit status."""
    print()
    width = max(len(n) for n, _, _ in results)
    for n, ok, d in results:
        print(f"{'PASS' if ok else 'FAIL'}  {n:<{width}}  {d}")
    bad = sum(not ok for _, ok, _ in results)
    print(f"\n{suite}: {len(results) - bad} passed, {bad} failed; guest run {elapsed:.1f} s")
    return 1 if bad else 0


def main() -> int:
    a, initrd, trace, mon = suite_setup(__doc__.splitlines()[0])
    t0 = time.monotonic()
    cmd = ["qemu-system-aarch64", "-M", "virt", "-cpu", "cortex-a57", "-smp", "1", "-m", "256",
           "-nodefaults", "-display", "none", "-no-reboot",
           "-kernel", str(a.kernel), "-initrd", str(initrd),
           "-append", "console=hvc0 quiet panic=-1 rdinit=/init",
           "-serial", "pty",
           "-device", "virtio-serial-device",
           "-trace", "pl011_write", "-trace", "pl061_set_output"]
    started = start_qemu(cmd, a.work, mon, trace)
    if started is None:
        return 1
    q, monitor = started
    assert q.stdin and q.stdout
    m = re.search(r"serial0: filename=pty:(/dev/pts/\d+)", monitor(b"info chardev"))
    if not m:
        q.kill()
        print("FAIL: QEMU did not report its pty", file=sys.stderr)
        return 1
    pty_path = m[1]
    pty_fd = os.open(pty_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(pty_fd, termios.TCSANOW)
    draining = threading.Event()
    draining.set()
    host_rx = bytearray()

    def drain() -> None:   # the guest's bytes while no slave listens
        while draining.is_set():
            r, _, _ = select.select([pty_fd], [], [], 0.05)
            if r and draining.is_set():
                try:
                    host_rx.extend(os.read(pty_fd, 4096))
                except BlockingIOError:
                    pass
    threading.Thread(target=drain, daemon=True).start()
    monitor(b"cont")

    guest: list[str] = []
    slave = None
    slave_out = b""
    done = False
    end = time.monotonic() + BOOT_TIMEOUT_S
    while time.monotonic() < end:
        r, _, _ = select.select([q.stdout], [], [], 1.0)
        if not r:
            if q.poll() is not None:
                break
            continue
        line = q.stdout.readline().decode(errors="replace").rstrip("\r\n")
        if not line:
            break
        guest.append(line)
        print(f"guest| +{time.monotonic() - t0:5.1f}s {line}", flush=True)
        if line == "READY-FOR-SLAVE":
            draining.clear()   # the slave is the only reader from now on
            slave = subprocess.Popen([str(a.slave), pty_path, "7", "3"], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT)
            assert slave.stdout
            ready = slave.stdout.readline()
            slave_out += ready
            q.stdin.write(b"go\n")
            q.stdin.flush()
        if line.startswith("GUEST-DONE"):
            done = True
            break
    try:
        q.wait(timeout=10)
    except subprocess.TimeoutExpired:
        q.kill()
        q.wait()
    if slave:
        try:
            out, _ = slave.communicate(timeout=10)
            slave_out += out
        except subprocess.TimeoutExpired:
            slave.kill()
            slave_out += slave.communicate()[0]
    os.close(pty_fd)
    elapsed = time.monotonic() - t0
    for text in slave_out.decode(errors="replace").splitlines():
        print(f"host slave| {text}")

    results: list[tuple[str, bool, str]] = []
    for line in guest:
        m = re.match(r"RESULT (\S+) (PASS|FAIL) ?(.*)", line)
        if m:
            results.append((m[1], m[2] == "PASS", m[3]))
    writes = parse_trace(trace)
    for line in guest:
        if line.startswith("TRACE "):
            parts = line.split()
            fields = dict(p.split("=", 1) for p in parts[2:])
            results.extend(judge_trace(parts[1], fields, writes))
    m = [g for g in guest if g.startswith("FAP-MASTER-EXIT")]
    replies = [g for g in guest if g.startswith("reply from 7:")]
    results.append(("fap_master_exchanges_with_host_slave",
                    bool(m) and m[0].endswith(" 0") and len(replies) == 3 and slave is not None
                    and slave.returncode == 0,
                    f"{len(replies)} of 3 replies, {m[0] if m else 'no exit line'}, host slave exit "
                    f"{slave.returncode if slave else None}"))
    results.append(("guest_completed", done, f"{len(writes)} pl011_write / pl061_set_output trace events"))
    return report("qemu suite", results, elapsed)


if __name__ == "__main__":
    sys.exit(main())
