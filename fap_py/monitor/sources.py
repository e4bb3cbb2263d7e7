"""Where the monitor's bytes come from: a raw byte file, a virtual-bus
capture, stdin or a live port opened receive-only through the C port layer.

Each source is an iterator of :class:`Chunk`; a live port also yields
``None`` when the line was idle until the decoder's deadline, so the
receiver's inter-byte gap can be applied.
"""
from __future__ import annotations

import os
import time
from typing import BinaryIO, Callable, Iterator, NamedTuple, Optional

from .._native import ffi, lib
from ..errors import error_from_code
from ..rs485 import RS485, RS485Mode, port_options
from ..vbus import read_capture

READ_SIZE = 65536


class Chunk(NamedTuple):
    data: bytes
    t: Optional[float]        # wire time of data[0], seconds (None: unknown)
    char_s: float             # seconds per byte on the wire (0: unknown)
    port: Optional[int]       # sender (virtual-bus captures only)
    now_ns: int               # CLOCK_MONOTONIC arrival (live inputs), else 0


def char_seconds(baud: int) -> float:
    """Wire time of one byte: 10 bits (start, 8 data, stop)."""
    return 10.0 / baud if baud else 0.0


def raw_file(fh: BinaryIO) -> Iterator[Chunk]:
    """Bytes as recorded from a port: no times, no senders."""
    while True:
        data = fh.read(READ_SIZE)
        if not data:
            return
        yield Chunk(data, None, 0.0, None, 0)


def capture_file(path: str) -> "tuple[int, Iterator[Chunk]]":
    """(baud of the capture, its data lines as chunks with times and senders)."""
    cap = read_capture(path)
    try:
        baud = int(cap.header.get("baud", "0"))
    except ValueError:
        baud = 0
    char_s = char_seconds(baud)

    def chunks() -> Iterator[Chunk]:
        for r in cap.records:
            yield Chunk(r.data, r.t_us / 1e6, char_s, r.port, 0)
    return baud, chunks()


def stream(fd: int, baud: int = 0) -> Iterator[Chunk]:
    """A pipe or file descriptor (stdin): arrival times, no senders."""
    char_s = char_seconds(baud)
    while True:
        data = os.read(fd, READ_SIZE)
        if not data:
            return
        now = time.time()
        yield Chunk(data, now - len(data) * char_s, char_s, None, time.monotonic_ns())


class LivePort:
    """A serial device opened receive-only (never transmits, RTS left alone).

    Opened through fap_port_open with rs485 mode ``none`` (unless told
    otherwise) and the
    exclusive lock (TIOCEXCL + flock) on, so a port another program holds
    is refused (-EBUSY) instead of being shared by accident.
    """

    def __init__(self, path: str, baud: int, rs485: Optional[RS485] = None) -> None:
        self.path = path
        self.baud = baud
        # mode NONE by default; an explicit RS-485 mode (kernel, soft RTS)
        # keeps a transceiver whose driver enable is on RTS off the bus
        opts = port_options(baud, rs485 if rs485 is not None else RS485(mode=RS485Mode.NONE))
        opts.exclusive = 1
        out = ffi.new("fap_port **")
        code = lib.fap_port_open(out, os.fsencode(path), opts)
        if code < 0:
            raise error_from_code(code, f"cannot open {path} at {baud} baud", path)
        self._port = out[0]
        self._buf = ffi.new("uint8_t[]", READ_SIZE)

    def close(self) -> None:
        if self._port != ffi.NULL:
            lib.fap_port_close(self._port)
            self._port = ffi.NULL

    def __enter__(self) -> "LivePort":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def chunks(self, deadline: Callable[[], Optional[int]], idle_s: Optional[float],
               stop: Callable[[], bool]) -> Iterator[Optional[Chunk]]:
        """Read until ``stop()``, or ``idle_s`` seconds without a byte (None: never).

        ``deadline()`` is the decoder's gap deadline (monotonic ns) or None.
        A read that times out (the gap deadline, or a quiet 200 ms) yields
        None: the line is idle.
        """
        char_s = char_seconds(self.baud)
        last = lib.fap_port_now_ns()
        while not stop():
            now = lib.fap_port_now_ns()
            wake = now + 200_000_000          # re-check stop() five times a second
            gap = deadline()
            if gap is not None:
                wake = min(wake, gap)
            if idle_s is not None:
                wake = min(wake, last + int(idle_s * 1e9))
            n = lib.fap_port_read(self._port, self._buf, READ_SIZE, max(wake, now))
            if n < 0:
                raise error_from_code(n, f"read {self.path}", self.path)
            now = lib.fap_port_now_ns()
            if n == 0:
                yield None
                if idle_s is not None and now >= last + int(idle_s * 1e9):
                    return
                continue
            last = now
            t = time.time()
            yield Chunk(bytes(ffi.buffer(self._buf, n)), t - n * char_s, char_s, None, now)


__all__ = ["Chunk", "LivePort", "capture_file", "char_seconds", "raw_file", "stream"]
