"""Another program on the port: an open descriptor (``port.holder``), a lock in
/proc/locks (``port.lock``) and a UUCP lock file (``port.uucp_lock``)."""
from __future__ import annotations

import os
from typing import Iterator, List, Optional, Tuple

from .._context import Context, PortInfo
from .._finding import Finding
from .._registry import check
from ._common import names_of, refers_to

#: descriptors looked at in all, at most (a huge /proc stays bounded)
FD_SCAN_MAX = 200000


def _who(ctx: Context, pid: str) -> str:
    comm = (ctx.read(f"/proc/{pid}/comm", 4096) or "?").strip() or "?"
    cmd = (ctx.read(f"/proc/{pid}/cmdline", 4096) or "").strip()
    return f"{comm} ({cmd[:200]})" if cmd else comm


def _pids(ctx: Context) -> List[str]:
    me = str(os.getpid()) if ctx.live else None
    return [p for p in ctx.listdir("/proc") if p.isdigit() and p != me]


def holders(ctx: Context, port: PortInfo) -> List[Tuple[str, str, str]]:
    """(pid, fd, link text) of every descriptor open on the port."""
    names = names_of(ctx, port)
    out: List[Tuple[str, str, str]] = []
    seen = 0
    for pid in _pids(ctx):
        for fd in ctx.listdir(f"/proc/{pid}/fd"):
            seen += 1
            if seen > FD_SCAN_MAX:
                return out
            link = ctx.readlink(f"/proc/{pid}/fd/{fd}")
            if link and refers_to(ctx, link, port, names):
                out.append((pid, fd, link))
    return out


@check("port.holder", "no other process has the port open")
def port_holder(ctx: Context) -> Iterator[Finding]:
    for port in ctx.ports():
        found = holders(ctx, port)
        if not found:
            blind = [] if not ctx.live or os.geteuid() == 0 else [
                f"as uid {os.geteuid()}: other users' /proc/PID/fd are not readable "
                "(run with sudo to see every process)"]
            yield Finding("port.holder", "ok", f"no other process has {port.device} open",
                          blind, port=port.device)
            continue
        for pid, fd, link in found:
            who = _who(ctx, pid)
            yield Finding("port.holder", "error",
                          f"pid {pid} {who.split(' ')[0]} has {port.device} open: two programs "
                          "on one port take each other's bytes (TIOCEXCL does not stop root)",
                          [f"/proc/{pid}/fd/{fd} -> {link}", f"pid {pid}: {who}"],
                          f"stop it: `systemctl status {pid}` names its unit (then `sudo "
                          f"systemctl stop UNIT`); else `kill {pid}`", port=port.device)


def _lock_lines(ctx: Context) -> List[Tuple[int, List[str]]]:
    out = []
    for n, line in enumerate(ctx.lines("/proc/locks"), 1):
        parts = line.replace("->", " ").split()
        if len(parts) >= 6 and parts[4].isdigit():
            out.append((n, parts))
    return out


@check("port.lock", "no process holds a lock on the port (/proc/locks)")
def port_lock(ctx: Context) -> Iterator[Finding]:
    locks = _lock_lines(ctx)
    if not locks:
        return
    for port in ctx.ports():
        st = ctx.stat(port.device)
        if st is None:
            continue
        for n, parts in locks:
            dev_ino = parts[5].split(":")
            if len(dev_ino) != 3 or dev_ino[2] != str(st.st_ino):
                continue
            if ctx.live and f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}" != \
                    f"{dev_ino[0]}:{dev_ino[1]}":
                continue
            pid = parts[4]
            if ctx.live and pid == str(os.getpid()):
                continue
            who = _who(ctx, pid)
            yield Finding("port.lock", "error",
                          f"pid {pid} {who.split(' ')[0]} holds a {parts[1]} lock on {port.device}",
                          [f"/proc/locks:{n}: {' '.join(parts)}", f"{port.device}: inode {st.st_ino}",
                           f"pid {pid}: {who}"],
                          f"stop pid {pid} (`systemctl status {pid}` names its unit)",
                          port=port.device)


def _lock_pid(text: str) -> Optional[int]:
    s = text.strip()
    if s.isdigit():
        return int(s)
    raw = text.encode("utf-8", errors="replace")[:4]
    if len(raw) == 4 and not s.isprintable():
        return int.from_bytes(raw, "little") or None
    return None


@check("port.uucp_lock", "no UUCP lock file names the port")
def port_uucp_lock(ctx: Context) -> Iterator[Finding]:
    for port in ctx.ports():
        for d in ("/run/lock", "/var/lock"):
            path = f"{d}/LCK..{port.name}"
            text = ctx.read(path, 256)
            if text is None:
                continue
            pid = _lock_pid(text)
            if pid is not None and ctx.exists(f"/proc/{pid}"):
                yield Finding("port.uucp_lock", "error",
                              f"pid {pid} {_who(ctx, str(pid)).split(' ')[0]} holds the UUCP lock "
                              f"of {port.device}",
                              [f"{path}: {text.strip()[:40]}", f"pid {pid}: {_who(ctx, str(pid))}"],
                              f"stop pid {pid} (`systemctl status {pid}` names its unit)",
                              port=port.device)
            else:
                yield Finding("port.uucp_lock", "warning",
                              f"a stale UUCP lock names {port.device}: programs that honour it "
                              "(minicom, ModemManager ...) refuse the port",
                              [f"{path}: {text.strip()[:40] or '(empty)'}",
                               f"pid {pid}: not running" if pid else "no pid in it"],
                              f"sudo rm {path}", port=port.device)
            break
