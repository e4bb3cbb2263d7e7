"""I/O helpers of the virtual bus tests: open a bus port the way a node does
and read with deadlines (never sleep to synchronise). A uniquely named module
(not conftest) so other components' test helpers cannot shadow it."""
from __future__ import annotations

import os
import select
import termios
import time
import tty

WAIT_S = 3.0   # generous deadline for data that must arrive


def open_port(path: str) -> int:
    """Open a bus port raw and non-blocking, stale input flushed."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    termios.tcflush(fd, termios.TCIOFLUSH)
    return fd


def read_exact(fd: int, n: int, timeout: float = WAIT_S) -> bytes:
    """Read until n bytes arrived or the deadline passed (returns what came)."""
    out = bytearray()
    deadline = time.monotonic() + timeout
    while len(out) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        ready, _, _ = select.select([fd], [], [], left)
        if not ready:
            continue
        try:
            chunk = os.read(fd, n - len(out))
        except BlockingIOError:
            continue
        if not chunk:
            break
        out += chunk
    return bytes(out)


def write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        try:
            view = view[os.write(fd, view):]
        except BlockingIOError:
            select.select([], [fd], [], 0.1)


def pending(fd: int) -> bool:
    """True if bytes are already waiting on fd."""
    ready, _, _ = select.select([fd], [], [], 0)
    return bool(ready)


