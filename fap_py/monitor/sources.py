"""Where the monitor's bytes come from: a raw byte file, a virtual-bus
capture, stdin or a live port opened receive-only through :class:`fap_py.port.Port`.

Each source is an iterator of :class:`Chunk`; a live port also yields
``None`` when the line was idle until the decoder's deadline, so the
receiver's inter-byte gap can be applied.
"""
from __future__ import annotations

import os
import select
import time
from dataclasses import replace
from typing import BinaryIO, Callable, Iterator, NamedTuple, Optional

from .._closing import Closing
from .._validate import U32, check_baud, check_int, check_path, check_seconds
from ..errors import ClosedError, InvalidTypeError
from ..port import MAX_READ, Port, PortStats
from ..rs485 import RS485, RS485Mode
from ..serve._url import is_daemon_url
from ..vbus import CaptureFormatError, CaptureRecord, iter_capture_file

#: bytes read at once: small enough that decoding one read takes well under
#: the 0.5 s within which a signal must end the monitor
READ_SIZE = 16384
#: how often a blocked stdin read looks at the stop request, seconds
POLL_S = 0.1
#: the latest capture time a record may carry (a pcap record's u32 seconds)
T_MAX_US = U32 * 1_000_000


class Chunk(NamedTuple):
    data: bytes
    t: Optional[float]        # wire time of data[0], seconds (None: unknown)
    char_s: float             # seconds per byte on the wire (0: unknown)
    port: Optional[int]       # sender (virtual-bus captures only)
    now_ns: int               # CLOCK_MONOTONIC arrival (live inputs), else 0


def char_seconds(baud: int) -> float:
    """Wire time of one byte: 10 bits (start, 8 data, stop); 0 for baud 0 (unknown)."""
    check_int(baud, "baud", 0, U32)
    return 10.0 / baud if baud else 0.0


def _check_stop(stop: object, what: str = "stop") -> None:
    if not callable(stop):
        raise InvalidTypeError(f"{what} must be callable, not {type(stop).__name__}")


def _never() -> bool:
    return False


def _reads(fd: int, stop: Callable[[], bool]) -> Iterator[bytes]:
    """What ``fd`` delivers, READ_SIZE at most at once, until its end or ``stop()``.

    Waits for bytes at most POLL_S at a time, so ``stop()`` ends even a pipe
    or fifo that never delivers (a regular file is always ready)."""
    while not stop():
        ready, _, _ = select.select([fd], [], [], POLL_S)
        if not ready:
            continue
        data = os.read(fd, READ_SIZE)
        if not data:
            return
        yield data


def raw_file(fh: BinaryIO, stop: Callable[[], bool] = _never) -> Iterator[Chunk]:
    """Bytes as recorded from a port: no times, no senders (until ``stop()``)."""
    if not callable(getattr(fh, "fileno", None)):
        raise InvalidTypeError(f"fh must be an open file, not {type(fh).__name__}")
    _check_stop(stop)
    try:
        fd = fh.fileno()
    except (OSError, ValueError) as exc:     # io.BytesIO, a closed file
        raise InvalidTypeError(f"fh must be an open file with a descriptor ({exc})") from None
    return _raw_chunks(fd, stop)


def _raw_chunks(fd: int, stop: Callable[[], bool]) -> Iterator[Chunk]:
    for data in _reads(fd, stop):
        yield Chunk(data, None, 0.0, None, 0)


def capture_file(path: str, stop: Callable[[], bool] = _never) -> "tuple[int, Iterator[Chunk]]":
    """(baud of the capture, its data lines as chunks with times and senders).

    The file is streamed (a regular file, bounded lines: vbus.capture_lines);
    a bad header rate, a time beyond 2**32 s or a sender beyond 255 is a
    CaptureFormatError naming the file.
    """
    _check_stop(stop)
    items = iter_capture_file(path)
    first = next(items, None)
    if first is None:     # not even a header: an empty file is no capture (a quiet bus has one)
        raise CaptureFormatError(f"{path}: empty file: not a capture (no '# fap-vbus-capture' "
                                 "header, no data line)")
    baud = 0
    if isinstance(first, dict):
        text = first.get("baud", "0")
        try:
            baud = int(text)
        except ValueError:
            baud = -1
        if not 0 <= baud <= U32:
            raise CaptureFormatError(f"{path}: header baud={text} is not a rate (0..{U32})")
    char_s = char_seconds(baud)

    def chunks() -> Iterator[Chunk]:
        for r in _records(first, items):
            if stop():
                return
            if r.t_us >= T_MAX_US or r.port > 255:
                raise CaptureFormatError(
                    f"{path}: data line t={r.t_us} port={r.port}: time beyond 2**32 s "
                    "or sender beyond 255")
            yield Chunk(r.data, r.t_us / 1e6, char_s, r.port, 0)
    return baud, chunks()


def _records(first: object, rest: Iterator[object]) -> Iterator[CaptureRecord]:
    """The data lines of a capture (the first item already read), events skipped."""
    if isinstance(first, CaptureRecord):
        yield first
    for item in rest:
        if isinstance(item, CaptureRecord):
            yield item


def stream(fd: int, baud: int = 0, stop: Callable[[], bool] = _never) -> Iterator[Chunk]:
    """A pipe or file descriptor (stdin): arrival times, no senders (until ``stop()``)."""
    check_int(fd, "fd", 0, 2**31 - 1)
    _check_stop(stop)
    return _stream_chunks(fd, char_seconds(baud), stop)


def _stream_chunks(fd: int, char_s: float, stop: Callable[[], bool]) -> Iterator[Chunk]:
    for data in _reads(fd, stop):
        now = time.time()
        yield Chunk(data, now - len(data) * char_s, char_s, None, time.monotonic_ns())


class _DaemonTap:
    """Every frame a daemon (``fap serve``) sends or receives, as it reports them: a
    ``fapd://`` URL given to ``fap monitor --port`` (docs/daemon.md, "monitor")."""

    def __init__(self, url: str) -> None:
        from ..serve import Connection

        self._conn = Connection(url, name="monitor")
        self._conn.call("monitor")
        self.baud = int(self._conn.welcome.get("baud") or 0)
        self.rx_bytes = 0

    def chunks(self, idle_s: Optional[float], stop: Callable[[], bool]) -> Iterator[Optional[Chunk]]:
        char_s = char_seconds(self.baud)
        last = time.monotonic()
        while not stop():
            ev = self._conn.next_event(0.2)
            now = time.monotonic()
            if ev is None or ev.get("event") != "frame":
                if ev is None:
                    yield None
                if idle_s is not None and now >= last + idle_s:
                    return
                continue
            last = now
            data = bytes.fromhex(ev.get("data", ""))
            self.rx_bytes += len(data)
            t = float(ev.get("t", time.time()))
            sender = 0 if ev.get("dir") == "tx" else 1     # 0: the daemon (master), 1: a slave
            yield Chunk(data, t - len(data) * char_s, char_s, sender, time.monotonic_ns())
            yield None                     # the daemon reports whole frames: each ends here

    def close(self) -> None:
        self._conn.close()


class LivePort(Closing):
    """A serial device opened receive-only (never transmits, RTS left alone), through
    :class:`fap_py.port.Port` (the package's one way to a device).

    Opened with RS-485 mode ``none`` (unless told otherwise) and the
    exclusive lock (TIOCEXCL + flock) on, so a port another program holds
    is refused (PortBusyError) instead of being shared by accident.
    """

    def __init__(self, path: str, baud: int, rs485: Optional[RS485] = None) -> None:
        path = check_path(path, "path")
        baud = check_baud(baud, "baud")
        if rs485 is not None and not isinstance(rs485, RS485):
            raise InvalidTypeError(f"rs485 must be None or an RS485, not {type(rs485).__name__}")
        self.path = path
        self.baud = baud
        self._tap: Optional[_DaemonTap] = None
        if is_daemon_url(path):       # fap serve's bus: a passive tap on every frame it moves
            self._tap = _DaemonTap(path)
            self.baud = self._tap.baud
            return
        # mode NONE by default; an explicit RS-485 mode (kernel, soft RTS)
        # keeps a transceiver whose driver enable is on RTS off the bus
        line = rs485 if rs485 is not None else RS485(mode=RS485Mode.NONE)
        self._port = Port(path, baud, replace(line, exclusive=True))

    @property
    def stats(self) -> PortStats:
        """The port's counters (bytes received, read errors ...)."""
        if self._tap is not None:
            return PortStats(rx_bytes=self._tap.rx_bytes)
        return self._port.stats

    def close(self) -> None:
        if self._tap is not None:
            self._tap.close()
            return
        self._port.close()


    @staticmethod
    def now_ns() -> int:
        """The clock of the chunks' ``now_ns`` and of decoder deadlines (CLOCK_MONOTONIC)."""
        return time.monotonic_ns()

    def chunks(self, deadline: Callable[[], Optional[int]], idle_s: Optional[float],
               stop: Callable[[], bool]) -> Iterator[Optional[Chunk]]:
        """Read until ``stop()``, or ``idle_s`` seconds without a byte (None: never).

        ``deadline()`` is the decoder's gap deadline (monotonic ns) or None.
        A read that times out (the gap deadline, or a quiet 200 ms) yields
        None: the line is idle.
        """
        _check_stop(deadline, "deadline")
        _check_stop(stop)
        if idle_s is not None:
            idle_s = check_seconds(idle_s, "idle_s")
        if self._tap is not None:
            return self._tap.chunks(idle_s, stop)
        if self._port.closed:
            raise ClosedError(f"{self.path}: closed")
        return self._chunks(deadline, idle_s, stop)

    def _chunks(self, deadline: Callable[[], Optional[int]], idle_s: Optional[float],
                stop: Callable[[], bool]) -> Iterator[Optional[Chunk]]:
        char_s = char_seconds(self.baud)
        idle_ns = None if idle_s is None else int(idle_s * 1e9)
        last = time.monotonic_ns()
        while not stop():
            now = time.monotonic_ns()
            wake = now + 200_000_000          # re-check stop() five times a second
            gap = deadline()
            if gap is not None:
                wake = min(wake, gap)
            if idle_ns is not None:
                wake = min(wake, last + idle_ns)
            data = self._port.read_until(MAX_READ, max(wake, now))
            now = time.monotonic_ns()
            if not data:
                yield None
                if idle_ns is not None and now >= last + idle_ns:
                    return
                continue
            last = now
            t = time.time()
            yield Chunk(data, t - len(data) * char_s, char_s, None, now)


__all__ = ["LivePort", "capture_file", "char_seconds", "raw_file", "stream"]
