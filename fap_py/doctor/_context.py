"""What the checks read, and the one helper that places every path beneath ``--root``.

Every path a check names is the analysed machine's (``/etc/group``,
``/dev/ttyUSB0``); :meth:`Context.host` turns it into the path to open here,
following symlinks so that an absolute link target stays beneath the root (a
tree copied off another machine). Reads are bounded (:data:`READ_MAX`), only
regular files are read (a fifo or a device never blocks a check), and every
failure (unreadable, a symlink loop, binary junk) reads as "absent": the checks
turn that into a finding or a skip, never a traceback. Each file read is
remembered for ``--bundle``.
"""
from __future__ import annotations

import getpass
import os
import re
import stat
import subprocess
from dataclasses import dataclass
from typing import Any, Callable, Dict, List, Optional, Tuple

from .. import sysfs_ports

#: the most bytes read from one file (a huge file is read this far)
READ_MAX = 1 << 20
#: the most bytes of the kernel log read (its end)
KERNEL_LOG_MAX = 4 << 20
#: the most entries listed from one directory
LIST_MAX = 20000
#: symlinks followed resolving one path before it counts as a loop
LINK_MAX = 40
#: the files `fap ports`' sysfs reader opens, in a tty's directories and above
_SYSFS_FILES = ("type", "latency_timer", "idVendor", "idProduct", "serial", "manufacturer",
                "product")
#: seconds a systemctl / dmesg call may take
TOOL_TIMEOUT_S = 3.0

#: where unit files live, most local first
UNIT_DIRS = ("/etc/systemd/system", "/run/systemd/system", "/usr/local/lib/systemd/system",
             "/lib/systemd/system", "/usr/lib/systemd/system")


@dataclass(frozen=True)
class Group:
    name: str
    gid: int
    members: Tuple[str, ...]
    line: int


@dataclass(frozen=True)
class User:
    name: str
    uid: int
    gid: int
    line: int


@dataclass
class PortInfo:
    """A port the doctor checks: the analysed path asked for, its canonical path,
    and what sysfs says (None for a pty or a path sysfs does not list)."""

    asked: str
    device: str
    sysfs: Optional[sysfs_ports.SerialPort] = None

    @property
    def name(self) -> str:
        return os.path.basename(self.device)


@dataclass
class Unit:
    name: str
    path: str        # analysed path of the unit file
    text: str

    def values(self, key: str) -> List[Tuple[int, str]]:
        """(line number, value) of every ``key=`` line."""
        out = []
        for n, line in enumerate(self.text.splitlines(), 1):
            k, sep, v = line.strip().partition("=")
            if sep and k.strip() == key:
                out.append((n, v.strip()))
        return out


class Context:
    """The analysed machine (``root``: ``/`` is this one) and the checks' options."""

    def __init__(self, root: str = "/", port: Optional[str] = None, user: Optional[str] = None,
                 kernel_log: Optional[str] = None, baud: Optional[int] = None,
                 probe: Optional[bool] = None,
                 prober: Optional[Callable[[str], Dict[str, Any]]] = None) -> None:
        self.root = os.path.abspath(root)
        self.live = self.root == "/"
        #: a bare name (``ttyUSB0``) is a /dev name
        self.asked_port = f"/dev/{port}" if port and "/" not in port else port
        self.baud = baud
        #: `fap ports`' probe of a device (RS-485 ioctls, baud, busy), handed in by the
        #: command line (a library room does not import it); None: not probed
        self.prober = prober
        #: open the ports (RS-485 ioctls, termios): only on this machine
        self.probe = (self.live and prober is not None) if probe is None else probe
        self.kernel_log_file = kernel_log
        self.files_read: Dict[str, str] = {}    # analysed path -> host path
        self._cache: Dict[str, Optional[str]] = {}
        self._klog: Optional[List[str]] = None
        self.kernel_log_source: Optional[str] = None
        self._groups: Optional[List[Group]] = None
        self._users: Optional[List[User]] = None
        self._units: Optional[Dict[str, Unit]] = None
        self._ports: Optional[List[PortInfo]] = None
        self._all_ports: Optional[List[sysfs_ports.SerialPort]] = None
        #: why the copied /sys was not read (an evidence line), or None
        self.sysfs_problem: Optional[str] = None
        self.user_source = "--user"
        self.user = user if user else self._default_user()

    # -- paths ---------------------------------------------------------------
    def host(self, path: str) -> Optional[str]:
        """The path to open here for the analysed machine's ``path``: beneath the
        root, symlinks followed inside it; None on a loop or a bad path."""
        if self.live:
            return path
        canon = self.canonical(path)
        return None if canon is None else self._join(canon)

    def _join(self, analysed: str) -> str:
        return os.path.join(self.root, analysed.lstrip("/"))

    def canonical(self, path: str) -> Optional[str]:
        """The analysed machine's ``path`` with every symlink resolved (the
        machine's own view: absolute targets from its ``/``); None on a loop."""
        if not isinstance(path, str) or "\0" in path:
            return None
        if self.live:
            try:
                return os.path.realpath(path, strict=False)
            except (OSError, ValueError):
                return None
        todo = list(reversed(path.split("/")))
        cur = "/"
        links = 0
        while todo:
            c = todo.pop()
            if c in ("", "."):
                continue
            if c == "..":
                cur = os.path.dirname(cur)
                continue
            nxt = os.path.join(cur, c)
            h = self._join(nxt)
            if os.path.islink(h):
                links += 1
                if links > LINK_MAX:
                    return None
                try:
                    target = os.readlink(h)
                except OSError:
                    return None
                if target.startswith("/"):
                    cur = "/"
                todo.extend(reversed(target.split("/")))
                continue
            cur = nxt
        return cur

    def stat(self, path: str, follow: bool = True) -> Optional[os.stat_result]:
        h = self.host(path) if follow else self._join(path) if not self.live else path
        if h is None:
            return None
        try:
            return os.stat(h) if follow else os.lstat(h)
        except (OSError, ValueError):
            return None

    def exists(self, path: str) -> bool:
        return self.stat(path) is not None

    def isdir(self, path: str) -> bool:
        st = self.stat(path)
        return st is not None and stat.S_ISDIR(st.st_mode)

    def readlink(self, path: str) -> Optional[str]:
        """The text of the link at ``path`` (its parent directories resolved), or None."""
        parent = self.host(os.path.dirname(path) or "/")
        if parent is None:
            return None
        try:
            return os.readlink(os.path.join(parent, os.path.basename(path)))
        except (OSError, ValueError):
            return None

    def listdir(self, path: str) -> List[str]:
        h = self.host(path)
        if h is None:
            return []
        try:
            with os.scandir(h) as it:
                out = []
                for e in it:
                    out.append(e.name)
                    if len(out) >= LIST_MAX:
                        break
        except (OSError, ValueError):
            return []
        return sorted(out)

    def read(self, path: str, limit: int = READ_MAX, tail: bool = False) -> Optional[str]:
        """The text of a regular file (at most ``limit`` bytes; its end with ``tail``),
        undecodable bytes replaced, NULs as spaces; None when absent or unreadable."""
        key = f"{path}\0{limit}\0{tail}"
        if key in self._cache:
            return self._cache[key]
        text = None
        h = self.host(path)
        if h is not None:
            text = _read_regular(h, limit, tail)
            if text is not None:
                self.files_read[path] = h
        self._cache[key] = text
        return text

    def lines(self, path: str) -> List[str]:
        text = self.read(path)
        return [] if text is None else text.splitlines()

    # -- users and groups ----------------------------------------------------
    def groups(self) -> List[Group]:
        if self._groups is None:
            self._groups = []
            for n, line in enumerate(self.lines("/etc/group"), 1):
                parts = line.strip().split(":")
                if len(parts) < 4 or not parts[0] or line.startswith("#"):
                    continue
                gid = _int(parts[2])
                if gid is None:
                    continue
                members = tuple(m.strip() for m in parts[3].split(",") if m.strip())
                self._groups.append(Group(parts[0], gid, members, n))
        return self._groups

    def users(self) -> List[User]:
        if self._users is None:
            self._users = []
            for n, line in enumerate(self.lines("/etc/passwd"), 1):
                parts = line.strip().split(":")
                if len(parts) < 4 or not parts[0] or line.startswith("#"):
                    continue
                uid, gid = _int(parts[2]), _int(parts[3])
                if uid is None or gid is None:
                    continue
                self._users.append(User(parts[0], uid, gid, n))
        return self._users

    def group_by_gid(self, gid: int) -> Optional[Group]:
        return next((g for g in self.groups() if g.gid == gid), None)

    def group_by_name(self, name: str) -> Optional[Group]:
        return next((g for g in self.groups() if g.name == name), None)

    def user_by_name(self, name: str) -> Optional[User]:
        return next((u for u in self.users() if u.name == name), None)

    def gids_of(self, name: str) -> List[int]:
        """The groups /etc/group and /etc/passwd give user ``name`` (primary first)."""
        u = self.user_by_name(name)
        out = [u.gid] if u else []
        out += [g.gid for g in self.groups() if name in g.members and g.gid not in out]
        return out

    def _default_user(self) -> Optional[str]:
        if self.live:
            self.user_source = "the invoking user"
            name = os.environ.get("SUDO_USER") if os.geteuid() == 0 else None
            try:
                return name or getpass.getuser()
            except (KeyError, OSError):
                return None
        for unit in self.units().values():
            if "fap" not in unit.name:
                continue
            for _, v in unit.values("User"):
                if v:
                    self.user_source = f"User= of {unit.path}"
                    return v
        self.user_source = "none (give --user)"
        return None

    # -- the kernel log --------------------------------------------------------
    def kernel_log(self) -> List[str]:
        if self._klog is not None:
            return self._klog
        text = None
        if self.kernel_log_file:
            text = _read_regular(self.kernel_log_file, KERNEL_LOG_MAX, True)
            if text is not None:
                self.kernel_log_source = self.kernel_log_file
                self.files_read["kernel-log"] = self.kernel_log_file
        else:
            for p in ("/var/log/kern.log", "/dmesg", "/var/log/dmesg"):
                text = self.read(p, KERNEL_LOG_MAX, tail=True)
                if text is not None:
                    self.kernel_log_source = p
                    break
            if text is None and self.live:
                text = _run(["dmesg"])
                if text is not None:
                    self.kernel_log_source = "dmesg"
        self._klog = [] if text is None else text.splitlines()
        return self._klog

    # -- systemd -------------------------------------------------------------
    def units(self) -> Dict[str, Unit]:
        """Unit files by name, the most local directory winning."""
        if self._units is None:
            self._units = {}
            for d in UNIT_DIRS:
                for name in self.listdir(d):
                    if name in self._units or not name.endswith((".service", ".socket")):
                        continue
                    p = f"{d}/{name}"
                    text = self.read(p, 65536)
                    if text is not None:
                        self._units[name] = Unit(name, p, text)
        return self._units

    def systemd_live(self) -> bool:
        return self.live and os.path.isdir("/run/systemd/system")

    def unit_enabled(self, name: str) -> Tuple[Optional[bool], str]:
        """(enabled?, evidence): from systemctl when systemd runs here, else from
        the ``*.wants`` links (and a mask: a link to /dev/null) beneath the root.
        None: the unit is not installed."""
        if self.systemd_live():
            out = _run(["systemctl", "is-enabled", name])
            if out is not None:
                state = out.strip() or "unknown"
                if state in ("not-found", ""):
                    return None, f"systemctl is-enabled {name}: {state}"
                return state in ("enabled", "enabled-runtime", "static", "alias"), \
                    f"systemctl is-enabled {name}: {state}"
        if self.readlink(f"/etc/systemd/system/{name}") == "/dev/null":
            return False, f"/etc/systemd/system/{name} -> /dev/null (masked)"
        wants = "/etc/systemd/system"
        for d in self.listdir(wants):
            link = f"{wants}/{d}/{name}"
            if d.endswith(".wants") and (self.readlink(link) is not None or self.exists(link)):
                return True, f"{link} (enabled)"
        installed = any(self.exists(f"{d}/{name}") for d in UNIT_DIRS)
        return (False, f"{name} installed, no *.wants link") if installed else \
            (None, f"{name}: no unit file")

    # -- ports -----------------------------------------------------------------
    def all_ports(self) -> List[sysfs_ports.SerialPort]:
        """The ports `fap ports` lists (:func:`fap_py.sysfs_ports.list_ports`), or none when
        a copied /sys holds a file it would block on or read whole (:attr:`sysfs_problem`)."""
        if self._all_ports is None:
            self._all_ports = []
            self.sysfs_problem = None if self.live else self._sysfs_hazard()
            if self.sysfs_problem is None:
                try:
                    self._all_ports = sysfs_ports.list_ports(self._join("/sys"), self._join("/dev"))
                except Exception:   # a hostile /sys: no ports rather than a traceback
                    self.sysfs_problem = "/sys/class/tty: unreadable"
        return self._all_ports

    def _sysfs_hazard(self) -> Optional[str]:
        """The first file of a copied /sys that `fap ports`' reader would block on (a fifo,
        a device) or read whole (larger than READ_MAX), as an evidence line; else None."""
        cls = self._join("/sys/class/tty")
        for name in self.listdir("/sys/class/tty"):
            for base in (os.path.join(cls, name), os.path.join(cls, name, "device")):
                d = os.path.realpath(base)
                for _ in range(5):
                    for f in _SYSFS_FILES:
                        try:
                            st = os.stat(os.path.join(d, f))
                        except (OSError, ValueError):
                            continue
                        if not stat.S_ISREG(st.st_mode) or st.st_size > READ_MAX:
                            shown = os.path.relpath(os.path.join(d, f), self.root)
                            return f"/{shown}: not a small regular file"
                    d = os.path.dirname(d)
        return None

    def ports(self) -> List[PortInfo]:
        """The ports to check: PORT, else every port sysfs lists."""
        if self._ports is None:
            listed = {p.name: p for p in self.all_ports()}
            if self.asked_port:
                canon = self.canonical(self.asked_port) or self.asked_port
                self._ports = [PortInfo(self.asked_port, canon, listed.get(os.path.basename(canon)))]
            else:
                self._ports = [PortInfo(f"/dev/{n}", f"/dev/{n}", p) for n, p in listed.items()]
        return self._ports


def _int(text: str) -> Optional[int]:
    text = text.strip()
    return int(text) if text.isdigit() and len(text) < 12 else None


def _read_regular(path: str, limit: int, tail: bool = False) -> Optional[str]:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except (OSError, ValueError):
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return None
        if tail and st.st_size > limit:
            os.lseek(fd, st.st_size - limit, os.SEEK_SET)
        chunks, left = [], limit
        while left > 0:
            b = os.read(fd, min(left, 65536))
            if not b:
                break
            chunks.append(b)
            left -= len(b)
        data = b"".join(chunks)
    except OSError:
        return None
    finally:
        os.close(fd)
    return data.decode("utf-8", errors="replace").replace("\0", " ")


def _run(cmd: List[str]) -> Optional[str]:
    try:
        r = subprocess.run(cmd, capture_output=True, timeout=TOOL_TIMEOUT_S,
                           stdin=subprocess.DEVNULL)
    except (OSError, subprocess.SubprocessError):
        return None
    if r.returncode != 0 and not r.stdout:
        return None
    return r.stdout[:KERNEL_LOG_MAX].decode("utf-8", errors="replace")


#: a vendor:product the kernel log names (``idVendor=1a86, idProduct=7523``)
USB_ID_RE = re.compile(r"idVendor=([0-9a-fA-F]{4}), idProduct=([0-9a-fA-F]{4})")

__all__ = ["Context", "Group", "PortInfo", "Unit", "User", "READ_MAX"]
