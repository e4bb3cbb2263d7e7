"""What several checks share: the device node's owner and mode, the names a port goes by."""
from __future__ import annotations

import os
import re
import stat
from typing import List, Optional, Set, Tuple

from .._context import Context, PortInfo

USB_NAME_RE = re.compile(r"^tty(USB|ACM)\d+$")
#: a name a unit file may give without /dev/ (ttyS0, ttyAMA0, ttyUSB0, ttymxc1 ...)
TTY_NAME_RE = re.compile(r"^tty[A-Za-z]+\d+$")


def device_owner(ctx: Context, port: PortInfo) -> Optional[Tuple[int, int, int, str]]:
    """(uid, gid, permission bits, evidence line) of the port's node, or None."""
    st = ctx.stat(port.device)
    if st is None:
        return None
    mode = stat.S_IMODE(st.st_mode)
    g = ctx.group_by_gid(st.st_gid)
    gname = g.name if g else f"gid {st.st_gid}"
    return st.st_uid, st.st_gid, mode, \
        f"{port.device}: owner uid {st.st_uid}, group {gname} (gid {st.st_gid}), mode {mode:04o}"


def group_name(ctx: Context, gid: int) -> str:
    g = ctx.group_by_gid(gid)
    return g.name if g else str(gid)


def group_line(ctx: Context, gid: int) -> List[str]:
    g = ctx.group_by_gid(gid)
    if g is None:
        return [f"/etc/group: no group with gid {gid}"]
    return [f"/etc/group:{g.line}: {g.name}:x:{g.gid}:{','.join(g.members)}"]


def names_of(ctx: Context, port: PortInfo) -> Set[str]:
    """Paths that name the port: as asked, canonical, and its by-id link."""
    out = {port.asked, port.device}
    if port.sysfs and port.sysfs.by_id:
        out.add("/dev/" + os.path.relpath(port.sysfs.by_id, ctx.host("/dev") or "/dev"))
    return out


def refers_to(ctx: Context, link: str, port: PortInfo, names: Set[str]) -> bool:
    """Whether a symlink's text (a /proc/PID/fd entry) is the port."""
    if link in names:
        return True
    return link.startswith("/dev/") and ctx.canonical(link) == port.device


def mentions(text: str, port: PortInfo, names: Set[str]) -> Optional[int]:
    """The first line (1-based) of ``text`` that names the port, or None."""
    words = names | ({port.name} if TTY_NAME_RE.match(port.name) else set())
    pat = re.compile(r"(?<![\w./-])(" + "|".join(re.escape(n) for n in sorted(words))
                     + r")(?![\w.-])")
    for n, line in enumerate(text.splitlines(), 1):
        if pat.search(line):
            return n
    return None
