"""The C port layer (``include/fap_port.h``) for Python code: one open serial device.

:class:`Port` opens a device path with a baud rate and the RS-485 line
options every libfap protocol uses (:class:`fap_py.fap.RS485`: direction
mode kernel / soft RTS / none, RTS delays, echo suppression, turnaround,
exclusive lock) and offers what a pure-Python protocol needs: write all
bytes, read with a deadline, flush input, reopen after the device vanished.

Every call goes into C; cffi releases the GIL around it, so a thread blocked
in :meth:`Port.read` does not hold up the rest of the program.

>>> from fap_py.port import Port
>>> with Port("/dev/ttyUSB0", 115200) as port:             # doctest: +SKIP
...     port.write(b"\\x01\\x02")
...     reply = port.read(16, timeout=0.1)
"""
from __future__ import annotations

import errno as _errno
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Any, Optional, Union

from ._handle import WAIT_SLICE, NativeHandle
from ._interruptible import interruptibly as _interruptibly  # the one rule (fap_py/_interruptible.py)
from ._stats import Counters, stats_from_c
from ._validate import check_bytes, check_seconds
from .errors import (  # PortBusyError, PortGoneError: re-exported, they used to live here
    ClosedError,
    FapError,
    InvalidTypeError,
    InvalidValueError,
    PortBusyError,
    PortError,
    PortGoneError,
    error_from_code,
)
from .rs485 import DEFAULT_BAUD, RS485, RS485Mode, port_options

log = logging.getLogger(__name__)

PathLike = Union[str, bytes, "os.PathLike[str]", "os.PathLike[bytes]"]

#: the longest single read (the C layer takes any size; this bounds the buffer)
MAX_READ = 4096
#: fap_port_read's "wait forever"
_FOREVER_NS = (1 << 63) - 1
#: longest single wait inside C: a close() from another thread is noticed within it
_SLICE_NS = int(WAIT_SLICE * 1e9)


def _is_tty(path: bytes) -> bool:
    """Whether ``path`` is a terminal (only asked on an open that failed)."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        return os.isatty(fd)
    finally:
        os.close(fd)


def port_error(code: int, what: str, path: Optional[str]) -> FapError:
    """The exception for a negative ``fap_port_*`` return code (busy and gone
    included: :func:`fap_py.errors.error_from_code`; -ECANCELED, a wait ended
    by close(): ClosedError)."""
    if code == -_errno.ECANCELED:
        return ClosedError(f"{path or 'port'}: {what}: port closed")
    return error_from_code(code, what, path)


@dataclass(frozen=True)
class PortStats(Counters):
    """Counters of one port (``fap_port_stats``)."""

    tx_bytes: int = 0
    rx_bytes: int = 0
    echo_bytes: int = 0
    collisions: int = 0
    write_errors: int = 0
    read_errors: int = 0
    reopens: int = 0
    rt_refused: int = 0   #: an I/O thread's real-time settings refused after the open


def check_timeout(value: Any, what: str = "timeout", *, zero_ok: bool = True) -> float:
    """``value`` as seconds: a finite number >= 0 (> 0 unless ``zero_ok``),
    checked by the package's one rule (:func:`fap_py._validate.check_seconds`)."""
    return check_seconds(value, what, lo_open=not zero_ok)


class Port(NativeHandle):
    """One serial device opened through libfap's port layer.

    :param path: the device (``/dev/ttyUSB0``, a pty, a virtual-bus port), or an
        Ethernet serial server's ``tcp://HOST:PORT`` / ``rfc2217://HOST:PORT``
        (docs/port.md, "Network transports"; a note from the server's set-up,
        such as an RFC 2217 option it never answered, is logged at WARNING).
    :param baudrate: any standard termios rate.
    :param rs485: line options (:class:`fap_py.fap.RS485`); None = the port
        layer's defaults (mode AUTO, exclusive lock, no echo suppression).

    Raises :class:`PortBusyError` when another opener holds the device,
    :class:`~fap_py.errors.InvalidValueError` for a bad baud rate or option,
    :class:`~fap_py.errors.PortError` for anything else the OS refuses.
    One thread reads at a time (the read buffer is the port's own); writes
    may come from another thread (the C layer serialises them).
    """

    _kind = "port"

    def __init__(self, path: PathLike, baudrate: int = DEFAULT_BAUD, rs485: Optional[RS485] = None) -> None:
        super().__init__()
        if not isinstance(path, (str, bytes, os.PathLike)):
            raise InvalidTypeError(f"path must be a str or path, not {type(path).__name__}")
        raw = os.fsencode(path)
        if not raw or b"\0" in raw:
            raise InvalidValueError(f"bad device path {path!r}")
        self.path = os.fsdecode(raw)
        po = port_options(baudrate, rs485)  # validates baud and options before C sees them
        self.rs485: RS485 = rs485 if rs485 is not None else RS485()
        from ._native import ffi, lib

        self._ffi, self._lib = ffi, lib
        # a close() from another thread writes here: a write the line does not
        # take, or any wait in C, ends at once (fap_port_open_cancellable)
        self._cancel_fd = os.eventfd(0, os.EFD_CLOEXEC | os.EFD_NONBLOCK)
        self._cancel_ref = ffi.new("int *", self._cancel_fd)
        out = ffi.new("fap_port **")
        if b"://" in raw:   # a network open waits (lookup, connect, RFC 2217): Ctrl-C ends it
            rc = _interruptibly(lambda: lib.fap_port_open_cancellable(out, raw, po, self._cancel_ref),
                                self._cancel_fd,
                                lambda r: r == 0 and lib.fap_port_close(out[0]))
        else:
            rc = lib.fap_port_open_cancellable(out, raw, po, self._cancel_ref)
        if rc:
            os.close(self._cancel_fd)
            self._cancel_fd = -1
            if rc == -_errno.ENOTTY and self.rs485.mode == RS485Mode.KERNEL and _is_tty(raw):
                # a terminal that refuses TIOCSRS485: say so, not "Inappropriate ioctl"
                raise PortError(_errno.ENOTTY, "open: the device has no kernel RS-485 "
                                "(TIOCSRS485: ENOTTY); use soft RTS or none (--rs485 soft|none)",
                                self.path)
            raise port_error(rc, "open", self.path)
        # the real-time option (docs/realtime.md): the thread doing the I/O takes it
        self._rt = bool(po.rt.policy or po.rt.cpus)
        self._buf = ffi.new("unsigned char[]", MAX_READ)
        self._buffer = ffi.buffer(self._buf)
        self.baudrate = int(lib.fap_port_baud(out[0]))
        note = ffi.new("char[]", 512)
        if lib.fap_port_warning(out[0], note, 512):   # a network server's quirk, open went on
            text = ffi.string(note).decode(errors="replace")
            if text.startswith("rfc2217:") and " ms" in text:   # the wait is the URL's option
                text += " (a slow server: wait longer with ?option_ms=N on the URL)"
            log.warning("%s: %s", self.path, text)
        self._adopt(out[0])

    # -- NativeHandle ----------------------------------------------------------

    def _interrupt(self) -> None:
        fd = getattr(self, "_cancel_fd", -1)
        if fd >= 0:
            os.eventfd_write(fd, 1)

    def _release(self, h: Any) -> None:
        self._lib.fap_port_close(h)
        fd, self._cancel_fd = self._cancel_fd, -1
        if fd >= 0:
            os.close(fd)

    def _fd(self, h: Any) -> int:
        return int(self._lib.fap_port_fd(h))

    def _label(self) -> str:
        return f"port {getattr(self, 'path', '?')}"

    def __repr__(self) -> str:
        state = "closed" if self.closed else f"{self.baudrate} baud, {self.mode.name}"
        return f"<Port {self.path} {state}>"

    # -- state -----------------------------------------------------------------

    @property
    def fd(self) -> int:
        """The file descriptor (for poll / an event loop); -1 while the device is gone."""
        return int(self._call(self._lib.fap_port_fd))

    @property
    def mode(self) -> RS485Mode:
        """The direction mode in force (never AUTO once open)."""
        return RS485Mode(self._call(self._lib.fap_port_mode))

    @property
    def stats(self) -> PortStats:
        """Byte, echo, collision, error and reopen counters."""
        st = self._ffi.new("fap_port_stats *")
        self._call(self._lib.fap_port_get_stats, st)
        return stats_from_c(PortStats, st)

    # -- I/O ---------------------------------------------------------------------

    def write(self, data: Union[bytes, bytearray, memoryview]) -> int:
        """Write every byte (turnaround wait, direction switching, drain, echo check).

        Raises :class:`~fap_py.errors.BusCollisionError` when echo suppression
        reads back something else, :class:`PortGoneError` when the device vanished.
        """
        if type(data) is bytes:  # cffi passes bytes to a const void * as they are
            buf: Any = data
            n = len(data)
        elif isinstance(data, (bytearray, memoryview)):
            if isinstance(data, memoryview) and not data.c_contiguous:
                data = data.tobytes()        # a strided view: from_buffer refuses it
            buf = self._ffi.from_buffer(data)
            n = len(buf)                     # bytes, also for a view of wider items
        else:
            raise InvalidTypeError(f"data must be bytes-like, not {type(data).__name__}")
        if self._rt:
            self._rt_enter()
        rc = self._call(self._lib.fap_port_write, buf, n)
        if rc < 0:
            raise port_error(rc, "write", self.path)
        return int(rc)

    def send(self, data: bytes) -> int:
        """:meth:`write` without ``tcdrain`` unless soft RTS or echo suppression needs it
        (``fap_port_send``): it returns once the bytes are queued, for a reply or a
        broadcast that nobody times from the write's return. ``data``: bytes-like."""
        data = check_bytes(data, "data", 0, 1 << 62)   # bytes-like, strided views too
        if self._rt:
            self._rt_enter()
        rc = self._call(self._lib.fap_port_send, data, len(data))
        if rc < 0:
            raise port_error(rc, "write", self.path)
        return int(rc)

    def read(self, n: int = MAX_READ, timeout: Optional[float] = None, *,
             deadline_ns: Optional[int] = None) -> bytes:
        """Up to ``n`` bytes, waiting for the first until ``timeout`` seconds
        (or the absolute ``deadline_ns`` of ``time.monotonic_ns()``) pass:
        b"" then. Neither given: do not wait."""
        if deadline_ns is None:
            deadline_ns = 0 if timeout is None else (
                time.monotonic_ns() + math.ceil(check_timeout(timeout) * 1e9))
        elif isinstance(deadline_ns, bool) or not isinstance(deadline_ns, int):
            raise InvalidTypeError(f"deadline_ns must be an int, not {type(deadline_ns).__name__}")
        elif not 0 <= deadline_ns <= _FOREVER_NS:
            raise InvalidValueError(f"deadline_ns must be 0..{_FOREVER_NS}, not {deadline_ns}")
        if type(n) is not int or not 0 < n <= MAX_READ:   # the bounds read_until has
            if isinstance(n, bool) or not isinstance(n, int):
                raise InvalidTypeError(f"n must be an int, not {type(n).__name__}")
            raise InvalidValueError(f"n must be 1..{MAX_READ}, not {n}")
        return self.read_until(n, min(deadline_ns, _FOREVER_NS))

    def read_until(self, n: int, deadline_ns: int) -> bytes:
        """Up to ``n`` bytes (1..MAX_READ), waiting for the first until the absolute
        ``deadline_ns`` (``time.monotonic_ns()``; 0 = do not wait): b"" then.

        The lean form of :meth:`read` for protocol loops: ``n`` and
        ``deadline_ns`` must be ints (a bad one raises InvalidValueError). A
        long wait runs in slices of ``WAIT_SLICE`` inside C, so a close() from
        another thread ends it.
        """
        if type(n) is not int or type(deadline_ns) is not int or not 0 < n <= MAX_READ \
                or not 0 <= deadline_ns <= _FOREVER_NS:
            raise InvalidValueError(f"read_until({n}, {deadline_ns}) out of range")
        read, buf = self._lib.fap_port_read, self._buf
        if self._rt:
            self._rt_enter()
        while True:
            step = deadline_ns
            if deadline_ns:
                step = min(deadline_ns, time.monotonic_ns() + _SLICE_NS)
            got = self._call(read, buf, n, step)
            if got > 0:
                return self._buffer[:got]
            if got < 0:
                raise port_error(got, "read", self.path)
            if step >= deadline_ns:
                return b""

    def transact(self, data: bytes, n: int, deadline_ns: int) -> bytes:
        """One request/reply round (``fap_port_transact``): drop input received and
        not read yet, write all of ``data``, then up to ``n`` bytes of the reply
        (0..MAX_READ; 0 = none awaited), waiting for the first until the absolute
        ``deadline_ns`` (``time.monotonic_ns()``; 0 = do not wait): b"" then.

        One call into C instead of three. The write skips ``tcdrain`` unless soft
        RTS or echo suppression needs it, so ``deadline_ns`` must allow for the
        request's own wire time. Raises like :meth:`write` and :meth:`read`.

        ``n=0`` is **send only**, by design (C's ``cap 0``): the pending input
        is dropped, ``data`` is written, and b"" comes back at once whatever
        ``deadline_ns`` says (a broadcast nobody answers). ``data=b""`` with
        ``n=0`` would do nothing but drop input: it is refused
        (InvalidValueError; :meth:`flush_input` does that).
        """
        if type(data) is not bytes and isinstance(data, (bytearray, memoryview)):
            data = bytes(data)               # bytes-like, strided views too
        if type(data) is not bytes or type(n) is not int or type(deadline_ns) is not int \
                or not 0 <= n <= MAX_READ or not 0 <= deadline_ns <= _FOREVER_NS:
            raise InvalidValueError(f"transact({type(data).__name__}, {n}, {deadline_ns}) out of range")
        if not data and not n:
            raise InvalidValueError("transact(b'', 0, ...): nothing to send and no reply awaited "
                                    "(n=0 is send only; flush_input() drops pending input)")
        step = deadline_ns
        if deadline_ns:
            step = min(deadline_ns, time.monotonic_ns() + _SLICE_NS)
        if self._rt:
            self._rt_enter()
        got = self._call(self._lib.fap_port_transact, data, len(data), self._buf, n, step)
        if got > 0:
            return self._buffer[:got]
        if got < 0:
            raise port_error(got, "transact", self.path)
        if step >= deadline_ns or not n:
            return b""
        return self.read_until(n, deadline_ns)  # a long wait goes on in slices

    def _rt_enter(self) -> None:
        """Apply the port's real-time settings to this thread (once per thread, in C)."""
        rc = self._call(self._lib.fap_port_rt_enter)
        if rc < 0:
            raise port_error(rc, "real-time", self.path)

    def flush_input(self) -> None:
        """Discard bytes received and not read yet (and unsent output)."""
        rc = self._call(self._lib.fap_port_flush)
        if rc < 0:
            raise port_error(rc, "flush", self.path)

    def reopen(self) -> None:
        """Close and open the same path again with the same options (after an unplug).

        Raises the open error if the device is not back yet; the port stays
        usable for further attempts.
        """
        if "://" not in self.path:
            rc = self._call(self._lib.fap_port_reopen)
        else:   # a network reopen waits (lookup, connect, negotiation): Ctrl-C ends it
            rc = _interruptibly(lambda: self._call(self._lib.fap_port_reopen), self._cancel_fd,
                                lambda r: self._uncancel())
        if rc < 0:
            raise port_error(rc, "reopen", self.path)

    def _uncancel(self) -> None:
        """Clear the cancel fd after a Ctrl-C ended a reopen (not after a close():
        that one's cancel stays), so the port remains usable for another try."""
        if not self._closing and self._cancel_fd >= 0:
            try:
                os.eventfd_read(self._cancel_fd)
            except BlockingIOError:
                pass


#: what :func:`port_kind` answers, from fap_port_kind (include/fap_port.h)
PORT_KINDS = ("device", "tcp", "rfc2217", "other", "invalid")


def port_kind(path: PathLike) -> str:
    """What a port string names, as the C port layer opens it (``fap_port_kind``).

    ``"device"``: no ``://`` (a tty, a pty; it may still not exist);
    ``"tcp"`` / ``"rfc2217"``: a network URL that parses (``tcp://HOST:PORT``,
    ``rfc2217://HOST:PORT``, query ``connect_ms`` / ``rtt_ms`` / ``option_ms``);
    ``"other"``: a URL of a scheme libfap does not open (pyserial's
    ``socket://``, ``loop://``); ``"invalid"``: a ``tcp://`` / ``rfc2217://``
    URL that does not parse (or a str that has no bytes form). Opens and
    looks up nothing. The one reading of a port string: code that needs to
    know what a path is asks here, not ``"://" in path``.

    ``path`` is a str, bytes or os.PathLike; anything else raises
    :class:`~fap_py.errors.InvalidTypeError`, an empty path or one holding a
    NUL byte (no device nor URL can have one) :class:`~fap_py.errors.InvalidValueError`.

    >>> port_kind("/dev/ttyUSB0"), port_kind("rfc2217://10.0.0.5:4001")   # doctest: +SKIP
    ('device', 'rfc2217')
    """
    if not isinstance(path, (str, bytes, os.PathLike)):
        raise InvalidTypeError(f"port must be a path or URL string (str, bytes or os.PathLike), "
                               f"not {type(path).__name__}")
    try:
        path = os.fspath(path)
    except TypeError as exc:     # an os.PathLike whose __fspath__ returns no path
        raise InvalidTypeError(f"port must be a path or URL string: {exc}") from None
    if isinstance(path, str):
        if "\0" in path:
            raise InvalidValueError(f"port {path[:60]!r} holds a NUL byte: no device or URL has one")
        try:
            raw = os.fsencode(path)
        except UnicodeError:
            return "invalid"
    else:
        raw = path
        if b"\0" in raw:
            raise InvalidValueError(f"port {raw[:60]!r} holds a NUL byte: no device or URL has one")
    if not raw:
        raise InvalidValueError("port must be a device path or URL, not an empty string")
    from ._native import lib

    k = lib.fap_port_kind(raw)
    return {lib.FAP_PORT_KIND_DEVICE: "device", lib.FAP_PORT_KIND_TCP: "tcp",
            lib.FAP_PORT_KIND_RFC2217: "rfc2217", lib.FAP_PORT_KIND_OTHER: "other"}.get(k, "invalid")


def is_network(path: PathLike) -> bool:
    """A ``tcp://`` or ``rfc2217://`` URL that parses (an Ethernet serial server).
    ``path`` is checked as :func:`port_kind` checks it (same errors)."""
    return port_kind(path) in ("tcp", "rfc2217")


def now_ns() -> int:
    """CLOCK_MONOTONIC now in ns: the clock of ``deadline_ns`` (same as ``time.monotonic_ns``)."""
    return time.monotonic_ns()


__all__ = ["MAX_READ", "PORT_KINDS", "Port", "PortBusyError", "PortGoneError", "PortStats",
           "RS485", "RS485Mode", "check_timeout", "is_network", "now_ns", "port_error", "port_kind"]
