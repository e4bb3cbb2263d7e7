"""Byte transport for the G485 master and simulator: one open serial port.

Two paths, one interface:

* a POSIX serial device or pty opened by pyserial (or a raw fd): ``poll``
  on the fd, then ``os.read`` of exactly the bytes wanted and ``os.write``
  of whole frames: no per-byte Python work, no busy-waiting, and no
  ``tcsetattr`` per call (pyserial's ``timeout`` setter reconfigures the
  port every time it is changed);
* any other pyserial object (``loop://``, ``socket://``, ``rfc2217://``,
  or a port in pyserial's ``rs485_mode``): its own ``read``/``write``.
"""
from __future__ import annotations

import errno
import math
import os
import select
import termios
import time
from typing import Any, Optional, Union

import serial

from ..errors import ClosedError, PortError

try:  # the POSIX implementation behind serial.Serial on Linux
    from serial.serialposix import Serial as _PosixSerial
except ImportError:  # pragma: no cover - non-POSIX
    _PosixSerial = None  # type: ignore[assignment,misc]


PortSpec = Union[str, "serial.SerialBase", int]


class Transport:
    """A port: ``read_some(n, deadline)``, ``write(data)``, ``flush_input()``."""

    def __init__(self, port: PortSpec, *, baudrate: int = 115200, **serial_kwargs: Any) -> None:
        self.fd: Optional[int] = None
        self.serial: Optional[serial.SerialBase] = None
        self._owns = False
        self._poll: Optional[select.poll] = None
        self.baudrate = baudrate
        if isinstance(port, int) and not isinstance(port, bool):
            self.fd = port
            self.name = f"fd {port}"
        elif isinstance(port, serial.SerialBase):
            self.serial = port
            self.name = str(port.port)
            self.baudrate = port.baudrate
        elif isinstance(port, (str, os.PathLike)):
            self.name = os.fspath(port)
            try:
                self.serial = serial.serial_for_url(self.name, baudrate=baudrate, timeout=0.05,
                                                    **serial_kwargs)
            except serial.SerialException as exc:
                err = getattr(exc, "errno", None)
                raise PortError(err or errno.EIO, None if err else str(exc), self.name) from None
            self._owns = True
        else:
            raise TypeError(f"port must be a path/URL, a pyserial object or an fd, not {port!r}")
        ser = self.serial
        if (ser is not None and _PosixSerial is not None and isinstance(ser, _PosixSerial)
                and ser.is_open and getattr(ser, "rs485_mode", None) is None):
            self.fd = ser.fileno()
        if self.fd is not None:
            self._poll = select.poll()
            self._poll.register(self.fd, select.POLLIN)
        self.closed = False

    @property
    def fast(self) -> bool:
        """True when I/O goes straight to the fd."""
        return self._poll is not None

    def read_some(self, n: int, deadline: float) -> bytes:
        """Up to ``n`` bytes, waiting until ``deadline`` (monotonic) for the first; b"" on timeout."""
        if self.closed:
            raise ClosedError(f"{self.name}: port closed")
        poll = self._poll
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return b""
            if poll is None:
                return self._read_serial(n, remaining)
            try:
                ready = poll.poll(math.ceil(remaining * 1000.0))
            except InterruptedError:  # pragma: no cover - PEP 475 retries already
                continue
            if not ready:
                return b""
            data = self._read_fd(n)
            if data:
                return data

    def read_within(self, n: int, timeout: float) -> bytes:
        """Fast path of fd ports (``fast``): one ``poll`` of up to ``timeout`` seconds,
        then one ``os.read`` of up to ``n`` bytes; b"" if nothing was readable.

        The caller goes on with :meth:`read_some` if the chunk is not what it
        wants, so a spurious wake-up returns b"" instead of retrying here.
        """
        if self.closed:
            raise ClosedError(f"{self.name}: port closed")
        if not self._poll.poll(math.ceil(timeout * 1000.0)):  # type: ignore[union-attr]
            return b""
        return self._read_fd(n)

    def _read_fd(self, n: int) -> bytes:
        """One ``os.read`` after ``poll`` said readable; b"" if nothing was there after all."""
        try:
            data = os.read(self.fd, n)  # type: ignore[arg-type]
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
        except serial.SerialException as exc:
            raise PortError(getattr(exc, "errno", None) or errno.EIO, str(exc), self.name) from None

    def write(self, data: bytes) -> None:
        """Write all of ``data``."""
        if self.closed:
            raise ClosedError(f"{self.name}: port closed")
        if self.fd is None:
            try:
                self.serial.write(data)  # type: ignore[union-attr]
            except serial.SerialException as exc:
                raise PortError(getattr(exc, "errno", None) or errno.EIO, str(exc), self.name) from None
            return
        try:
            done = os.write(self.fd, data)
        except BlockingIOError:
            done = 0
        except OSError as exc:
            raise PortError(exc.errno or errno.EIO, None, self.name) from None
        if done == len(data):
            return
        view = memoryview(data)[done:]  # a partial write (full tty buffer): finish it
        while view:
            try:
                done = os.write(self.fd, view)
            except BlockingIOError:
                select.select([], [self.fd], [], 1.0)
                continue
            except OSError as exc:
                raise PortError(exc.errno or errno.EIO, None, self.name) from None
            view = view[done:]

    def flush_input(self) -> None:
        """Drop bytes received but not read (before a retry)."""
        if self.closed:
            return
        try:
            if self.fd is not None:
                termios.tcflush(self.fd, termios.TCIFLUSH)
            else:
                self.serial.reset_input_buffer()  # type: ignore[union-attr]
        except (OSError, termios.error, serial.SerialException):
            pass  # a socket or a vanished port: the next read reports it

    def close(self) -> None:
        """Close the port if this object opened it."""
        if self.closed:
            return
        self.closed = True
        if self._owns and self.serial is not None:
            self.serial.close()
