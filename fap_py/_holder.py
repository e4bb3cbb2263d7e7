"""Who holds a serial device: the pid in a live UUCP lock file (``/var/lock/LCK..ttyX``,
or ``$FAP_LOCK_DIR``), else the flock holder /proc/locks names. Private; depends on
nothing in the package (:mod:`fap_py.errors` asks it to name the holder of a busy port).
"""
from __future__ import annotations

import os
from typing import Optional

#: where lock files live unless configured (FAP_LOCK_DIR overrides for openers)
DEFAULT_LOCK_DIR = "/var/lock"


def _lock_name(device: str, lock_dir: str) -> str:
    real = os.path.realpath(device)
    return os.path.join(lock_dir, "LCK.." + os.path.basename(real))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _read_pid(path: str) -> Optional[int]:
    try:
        with open(path, "rb") as f:
            raw = f.read(32)
    except OSError:
        return None
    if len(raw) == 4:                       # the binary form some old programs write
        pid = int.from_bytes(raw, "little")
    else:
        text = raw.decode("ascii", "replace").strip()
        pid = int(text) if text.isdigit() else 0
    return pid if pid > 0 and _alive(pid) else None


def _flock_holder(device: str) -> Optional[int]:
    """The pid /proc/locks names for a flock on ``device``'s inode."""
    try:
        st = os.stat(device)
        with open("/proc/locks") as f:
            lines = f.read().splitlines()
    except OSError:
        return None
    for line in lines:
        if "->" in line:
            continue
        parts = line.split()
        if len(parts) < 6:
            continue
        try:
            pid = int(parts[4])
            maj, mino, ino = parts[5].split(":")
            if int(maj, 16) == os.major(st.st_dev) and int(mino, 16) == os.minor(st.st_dev) \
                    and int(ino) == st.st_ino:
                return pid
        except ValueError:
            continue
    return None


def holder(device: str, lock_dir: Optional[str] = None) -> Optional[int]:
    """The pid holding ``device`` (UUCP lock file, then flock), or None."""
    lock_dir = lock_dir or os.environ.get("FAP_LOCK_DIR") or DEFAULT_LOCK_DIR
    pid = _read_pid(_lock_name(device, lock_dir))
    return pid if pid is not None else _flock_holder(device)


def describe(pid: int) -> str:
    """``pid 123 (fap serve --port ...)`` from /proc/PID/cmdline."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
    except OSError:
        argv = []
    if argv and os.path.basename(argv[0]).startswith("python") and len(argv) > 1:
        argv = argv[1:]
        if argv[0] == "-m" and len(argv) > 1:
            argv = argv[1:]
    cmd = " ".join(argv)[:120]
    return f"pid {pid} ({cmd})" if cmd else f"pid {pid}"


