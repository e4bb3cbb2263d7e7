"""Where the G485 master and simulator get their bytes: one small interface, two kinds of port.

* a device path (``/dev/ttyUSB0``, a pty, a virtual-bus port) is opened
  through libfap's C port layer (:class:`fap_py.port.Port`): RS-485 direction
  control (kernel / soft RTS), echo suppression, turnaround, the exclusive
  lock, deadline reads and reopen, exactly as every other protocol gets them;
* a pyserial URL (``socket://``, ``loop://``, ``spy://``; libfap's own ``tcp://`` and
  ``rfc2217://`` go through the C port layer like a device path), an
  open pyserial object or a raw fd goes through :class:`SerialIO`, a thin
  adapter over pyserial's own ``read``/``write`` (so ``spy://`` logs both
  directions) or over ``os.read``/``os.write`` for a raw fd.

Both offer ``read_some(n, deadline)``, ``read_within(n, timeout)``,
``read_nowait(n)``, ``write(data)``, ``flush_input()``, ``reopen()`` and
``close()``; ``fd`` is the descriptor to poll (None when there is none).
"""
from __future__ import annotations

import dataclasses
import errno
import math
import os
import select
import termios
import time
from typing import Any, Optional, Union

import serial

from .._handle import WAIT_SLICE
from ..errors import BusCollisionError, ClosedError, InvalidValueError, PortError
from ..port import Port, port_kind
from ..rs485 import RS485
from .errors import EchoMismatchError, G485ValueError

PortSpec = Union[str, "os.PathLike[str]", "serial.SerialBase", int]
#: longest poll of a reply wait: a close() from another thread is noticed within it
_SLICE_MS = int(WAIT_SLICE * 1000)
#: the most one read asks for (the C port layer's bound)
_MAX_N = 4096


def _n(n: int) -> int:
    """A read size: an int 1.._MAX_N (one type test on the hot path)."""
    if type(n) is not int or not 0 < n <= _MAX_N:
        raise G485ValueError(f"n must be an int 1..{_MAX_N}, not {n!r}")
    return n


def _secs(t: float, what: str, hi: float = 1e6) -> float:
    """A finite number of seconds 0..hi (NaN fails the comparison)."""
    if (type(t) is not float and type(t) is not int) or not 0 <= t <= hi:
        raise G485ValueError(f"{what} must be a number of seconds 0..{hi:g}, not {t!r}")
    return t


def _data(data: bytes) -> bytes:
    """Bytes to send: bytes-like (a bytearray, any memoryview) as bytes."""
    if type(data) is bytes:
        return data
    if isinstance(data, (bytearray, memoryview)):
        return bytes(data)
    raise G485ValueError(f"data must be bytes-like, not {type(data).__name__}")


def _is_url(name: str) -> bool:
    """A pyserial URL (``socket://`` ...): a scheme the C port layer does not
    open (fap_port_kind: "other"); libfap's own ``tcp://`` and ``rfc2217://``
    (also a malformed one: the C open says why) go through the C port layer
    like a device path."""
    return port_kind(name) == "other"


class PortIO:
    """A device path through the C port layer (see :class:`fap_py.port.Port`)."""

    fast = True  # one read returns what the C layer got: the master's exact-reply path applies

    def __init__(self, path: str, baudrate: int, rs485: Optional[RS485]) -> None:
        try:
            self.port = Port(path, baudrate, rs485)
        except InvalidValueError as exc:
            raise G485ValueError(str(exc)) from None
        p = self.port
        self.name = p.path
        self.baudrate = p.baudrate
        self._read = p.read_until
        self._write = p.send  # replies and broadcasts: nobody times them from the write's return
        self._transact = p.transact
        # waiting for a reply: poll here, then one read in C (the C read would first try a
        # read that fails with EAGAIN); not with echo suppression, whose parked input poll misses
        self._poller: Optional[select.poll] = None
        self._use_poll = not p.rs485.echo_suppression
        self._watch()

    @property
    def fd(self) -> Optional[int]:
        """The descriptor to poll (-1 while the device is gone)."""
        return self.port.fd

    @property
    def closed(self) -> bool:
        return self.port.closed

    def read_some(self, n: int, deadline: float) -> bytes:
        """Up to ``n`` bytes, waiting until ``deadline`` (``time.monotonic()``) for the first."""
        return self._read(_n(n), max(1, math.ceil(_secs(deadline, "deadline", 1e12) * 1e9)))

    def read_within(self, n: int, timeout: float) -> bytes:
        """Up to ``n`` bytes, waiting at most ``timeout`` seconds for the first (b"" if
        nothing came; the caller goes on with :meth:`read_some` if the chunk is short)."""
        _n(n)
        _secs(timeout, "timeout")
        poller = self._poller
        if poller is not None:
            ms = math.ceil(timeout * 1000.0)
            deadline = time.monotonic() + timeout
            # in slices: a close() from another thread ends the wait (ClosedError below)
            while not poller.poll(min(ms, _SLICE_MS)):
                if self.port.closed:
                    break
                ms = math.ceil((deadline - time.monotonic()) * 1000.0)
                if ms <= 0:
                    return b""
            return self._read(n, 0)
        return self._read(n, time.monotonic_ns() + math.ceil(timeout * 1e9))

    def exchange(self, data: bytes, n: int, timeout: float) -> bytes:
        """Drop stale input, write ``data``, then up to ``n`` bytes of the reply, waiting at
        most ``timeout`` seconds for the first (b"" if nothing came): one call into C
        (``fap_port_transact``). ``timeout`` must include the request's wire time."""
        try:
            return self._transact(_data(data), n,
                                  time.monotonic_ns() + math.ceil(_secs(timeout, "timeout") * 1e9))
        except BusCollisionError as exc:
            raise EchoMismatchError(f"{self.name}: {exc}") from None

    def send_fresh(self, data: bytes) -> None:
        """:meth:`flush_input` then :meth:`write` in one call into C (the reply is
        awaited elsewhere, e.g. by an event loop's reader)."""
        try:
            self._transact(_data(data), 0, 0)
        except BusCollisionError as exc:
            raise EchoMismatchError(f"{self.name}: {exc}") from None

    def _watch(self) -> None:
        """(Re)build the poller on the port's current fd (after open and after a reopen)."""
        fd = self.port.fd if self._use_poll and not self.port.closed else -1
        if fd >= 0:
            self._poller = select.poll()
            self._poller.register(fd, select.POLLIN)
        else:
            self._poller = None

    def read_nowait(self, n: int) -> bytes:
        """What is there now, up to ``n`` bytes (b"" if nothing)."""
        return self._read(_n(n), 0)

    def write(self, data: bytes) -> None:
        """Write all of ``data`` (direction switching, echo check in C; ``tcdrain`` only
        where soft RTS or echo suppression needs it: ``fap_port_send``)."""
        try:
            self._write(_data(data))
        except BusCollisionError as exc:
            raise EchoMismatchError(f"{self.name}: {exc}") from None

    def flush_input(self) -> None:
        """Drop bytes received but not read.

        By reading them, not with ``tcflush``: the port layer's flush also
        drops output, and on a pty (a virtual bus) a request written but not
        yet taken by the far end would be lost with it.
        """
        poller = self._poller
        if poller is not None and not poller.poll(0):
            return  # nothing waiting (the common case): one poll, no call into C
        read = self._read
        try:
            while read(4096, 0):
                pass
        except (PortError, ClosedError):
            self._poller = None  # a vanished port: the next read or write reports it

    def reopen(self) -> None:
        """Open the same path again (raises PortError while it is not back)."""
        self.port.reopen()
        self._watch()

    def close(self) -> None:
        self.port.close()


class SerialIO:
    """A pyserial URL or object, or a raw fd: the same interface as :class:`PortIO`.

    ``echo``: every write is read back and compared (what the C layer's echo
    suppression does for device paths).
    """

    fast = False

    def __init__(self, port: Union[str, "serial.SerialBase", int], baudrate: int, *, echo: bool = False,
                 **serial_kwargs: Any) -> None:
        self.serial: Optional[serial.SerialBase] = None
        self.fd: Optional[int] = None
        self._owns = False
        self.echo = echo
        self.baudrate = baudrate
        self.closed = False
        if isinstance(port, int) and not isinstance(port, bool):
            if port < 0:
                raise G485ValueError(f"fd must be >= 0, not {port}")
            try:
                os.fstat(port)
            except (OSError, OverflowError):
                raise G485ValueError(f"fd {port} is not an open file descriptor") from None
            self.fd = port
            self.name = f"fd {port}"
            self._poll = select.poll()
            self._poll.register(port, select.POLLIN)
        elif isinstance(port, serial.SerialBase):
            self.serial = port
            self.name = str(port.port)
            self.baudrate = port.baudrate
        else:
            self.name = str(port)
            try:
                self.serial = serial.serial_for_url(self.name, baudrate=baudrate, timeout=0.05,
                                                    **serial_kwargs)
            except (ValueError, TypeError) as exc:
                raise G485ValueError(f"{self.name}: {exc}") from None
            except serial.SerialException as exc:
                err = getattr(exc, "errno", None)
                raise PortError(err or errno.EIO, None if err else str(exc), self.name) from None
            self._owns = True

    def _check(self) -> None:
        if self.closed:
            raise ClosedError(f"{self.name}: port closed")

    def read_some(self, n: int, deadline: float) -> bytes:
        """Up to ``n`` bytes, waiting until ``deadline`` (monotonic) for the first; b"" on timeout."""
        _n(n)
        _secs(deadline, "deadline", 1e12)
        self._check()
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return b""
            if self.fd is None:
                return self._read_serial(n, remaining)
            if not self._poll.poll(math.ceil(remaining * 1000.0)):
                return b""
            data = self._read_fd(n)
            if data:
                return data

    def read_within(self, n: int, timeout: float) -> bytes:
        """Up to ``n`` bytes, waiting at most ``timeout`` seconds for the first."""
        return self.read_some(n, time.monotonic() + _secs(timeout, "timeout"))

    def read_nowait(self, n: int) -> bytes:
        """What is there now, up to ``n`` bytes."""
        _n(n)
        self._check()
        if self.fd is not None:
            return self._read_fd(n) if self._poll.poll(0) else b""
        ser = self._serial()
        try:
            waiting = ser.in_waiting
            return ser.read(min(n, waiting)) if waiting else b""
        except (serial.SerialException, OSError) as exc:
            raise PortError(getattr(exc, "errno", None) or errno.EIO, str(exc), self.name) from None

    def _serial(self) -> "serial.SerialBase":
        """The pyserial object (this adapter wraps one when it has no raw fd)."""
        ser = self.serial
        if ser is None:  # pragma: no cover - a raw fd never takes the pyserial branches
            raise ClosedError(f"{self.name}: no pyserial object")
        return ser

    def _raw_fd(self) -> int:
        fd = self.fd
        if fd is None:  # pragma: no cover - a pyserial object never takes the fd branches
            raise ClosedError(f"{self.name}: no file descriptor")
        return fd

    def _read_fd(self, n: int) -> bytes:
        try:
            data = os.read(self._raw_fd(), n)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise PortError(exc.errno or errno.EIO, None, self.name) from None
        if not data:
            raise PortError(errno.EIO, "port hung up (end of file)", self.name)
        return data

    def _read_serial(self, n: int, remaining: float) -> bytes:
        ser = self.serial
        assert ser is not None
        try:
            if ser.timeout != remaining:
                ser.timeout = remaining
            first = ser.read(1)
            if not first or n == 1:
                return first
            waiting = ser.in_waiting
            return first + (ser.read(min(n - 1, waiting)) if waiting else b"")
        except (serial.SerialException, OSError) as exc:
            raise PortError(getattr(exc, "errno", None) or errno.EIO, str(exc), self.name) from None

    def write(self, data: bytes) -> None:
        """Write all of ``data`` (and read its echo back when ``echo`` is on)."""
        data = _data(data)
        self._check()
        if self.fd is None:
            try:
                self._serial().write(data)
            except (serial.SerialException, OSError) as exc:
                raise PortError(getattr(exc, "errno", None) or errno.EIO, str(exc), self.name) from None
        else:
            view = memoryview(data)
            while view:
                try:
                    done = os.write(self.fd, view)
                except BlockingIOError:
                    select.select([], [self.fd], [], 1.0)
                    continue
                except OSError as exc:
                    raise PortError(exc.errno or errno.EIO, None, self.name) from None
                view = view[done:]
        if self.echo:
            self._read_echo(data)

    def _read_echo(self, frame: bytes) -> None:
        deadline = time.monotonic() + 0.02 + len(frame) * 20.0 / max(1, self.baudrate)
        got = b""
        while len(got) < len(frame):
            chunk = self.read_some(len(frame) - len(got), deadline)
            if not chunk:
                raise EchoMismatchError(f"{self.name}: echo incomplete ({len(got)} of {len(frame)} "
                                        "bytes): is echo really on?")
            got += chunk
        if got != frame:
            raise EchoMismatchError(f"{self.name}: echo {got.hex(' ')} differs from sent "
                                    f"{frame.hex(' ')} (collision or line fault)")

    def flush_input(self) -> None:
        """Drop bytes received but not read."""
        if self.closed:
            return
        try:
            if self.fd is not None:
                termios.tcflush(self.fd, termios.TCIFLUSH)
            else:
                self._serial().reset_input_buffer()
        except (OSError, termios.error, serial.SerialException):
            pass  # a socket or a vanished port: the next read reports it

    def reopen(self) -> None:
        """pyserial objects and raw fds are not reopened here."""
        raise PortError(errno.ENOTSUP, "reopen needs a device path", self.name)

    def close(self) -> None:
        """Close the port if this object opened it."""
        if self.closed:
            return
        self.closed = True
        if self._owns and self.serial is not None:
            self.serial.close()


IO = Union[PortIO, SerialIO]


def open_io(port: PortSpec, baudrate: int, *, rs485: Optional[RS485] = None, echo: bool = False,
            **serial_kwargs: Any) -> IO:
    """The transport for ``port``: :class:`PortIO` for a device path, :class:`SerialIO` otherwise.

    ``echo`` turns on echo suppression (the C layer's for a device path).
    Every bad argument raises a :class:`~fap_py.g485.errors.G485ValueError`.
    """
    if isinstance(baudrate, bool) or not isinstance(baudrate, int):
        raise G485ValueError(f"baudrate must be an int, not {type(baudrate).__name__}")
    if not 1 <= baudrate <= 0xFFFFFFFF:
        raise G485ValueError(f"baudrate must be a positive number of baud, not {baudrate}")
    if rs485 is not None and not isinstance(rs485, RS485):
        raise G485ValueError(f"rs485 must be an fap_py.RS485, not {type(rs485).__name__}")
    if not isinstance(echo, bool):
        raise G485ValueError(f"echo must be a bool, not {type(echo).__name__}")
    if isinstance(port, os.PathLike):
        port = os.fspath(port)
    if isinstance(port, str) and not _is_url(port):
        if serial_kwargs:
            raise G485ValueError(f"pyserial options {sorted(serial_kwargs)} apply to pyserial URLs "
                                 "and objects only; a device path takes rs485=fap_py.RS485(...)")
        if echo:
            rs485 = dataclasses.replace(rs485 or RS485(), echo_suppression=True)
        return PortIO(port, baudrate, rs485)
    if rs485 is not None:
        raise G485ValueError("RS-485 options need a device path (the C port layer); "
                             "pyserial URLs and objects carry their own")
    if not isinstance(port, (str, int, serial.SerialBase)) or isinstance(port, bool):
        raise G485ValueError(f"port must be a device path, a pyserial URL or object, or an fd, "
                             f"not {type(port).__name__}")
    return SerialIO(port, baudrate, echo=echo, **serial_kwargs)


__all__ = ["IO", "PortIO", "PortSpec", "SerialIO", "open_io"]
