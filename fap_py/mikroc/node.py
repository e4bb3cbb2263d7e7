"""What a mikroC master and slave share: a C context bound to a port this object
opened, its counters, the blocking and the asyncio receive."""
from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import Any, Optional, Union

from .. import _trace  # wire bytes on fap_py.wire.mikroc at DEBUG
from .._handle import NativeHandle, deadline_of, slice_ms
from .._interruptible import open_interruptibly
from .._native import ffi, lib
from .._stats import Counters, stats_from_c
from .._validate import check_path, check_timeout
from ..errors import FapTimeoutError, error_from_code
from ..rs485 import RS485, port_options
from .codec import Message
from .errors import _frame_error

__all__ = ["NodeStats"]

log = logging.getLogger(__name__)

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class NodeStats(Counters):
    """Counters of a master or slave (``mikrocRS485_stats``)."""

    frames: int      #: frames delivered
    errors: int      #: damaged frames for this node (and overruns)
    overruns: int    #: frames not stored because the last one was unread
    ignored: int     #: valid frames for another address or direction
    damaged: int     #: damaged frames heard, for any address


def _timeout_ms(timeout: Optional[float]) -> int:
    t = check_timeout(timeout)
    return -1 if t is None else int(t * 1000.0 + 0.999999)


class _Node(NativeHandle):
    """A mikroC context bound to a port this object opened (``fap_port_open``):
    the port's fd lets :meth:`areceive` wait in an asyncio loop."""

    _buffer_size = lib.MIKROC_RS485_MASTER_BUFFER
    _kind = "mikroC node"

    def __init__(self, port_path: PathLike, baudrate: int, rs485: Optional[RS485]) -> None:
        super().__init__()
        self.path = check_path(port_path)
        self._lock = threading.Lock()      # receive side: one receiver at a time
        self._tx_lock = threading.Lock()   # send side (may run beside a receive)
        self._ctx = ffi.new("mikrocRS485_ctx *")
        self._init_ctx()
        opts = port_options(baudrate, rs485)
        out = ffi.new("fap_port **")
        raw = os.fsencode(self.path)
        # the port keeps &cancel_ref[0] and reads it at each wait: the open's
        # eventfd while it runs (a network open: Ctrl-C ends it), then -1 (none)
        self._cancel_ref = ffi.new("int *", -1)

        def open_with(cancel_fd: int) -> int:
            self._cancel_ref[0] = cancel_fd or -1
            try:
                return int(lib.fap_port_open_cancellable(out, raw, opts, self._cancel_ref))
            finally:
                self._cancel_ref[0] = -1

        r = open_interruptibly(raw, open_with, lambda rc: rc == 0 and lib.fap_port_close(out[0]))
        if r < 0:
            raise error_from_code(r, "open", self.path)
        r = lib.mikrocRS485_CtxBind(self._ctx, out[0])
        if r < 0:  # pragma: no cover - a fresh context always binds
            lib.fap_port_close(out[0])
            raise error_from_code(r, "bind", self.path)
        self._adopt(out[0])
        self._tap = _trace.attach(lib.mikrocRS485_CtxSetTrace, self._ctx, "mikroc", self.path)
        log.debug("%s opened %s at %d baud", type(self).__name__, self.path, baudrate)

    def _init_ctx(self) -> None:
        raise NotImplementedError

    def _label(self) -> str:
        return f"{type(self).__name__} on {self.path}"

    def _release(self, port: Any) -> None:
        lib.mikrocRS485_CtxClose(self._ctx)   # unbinds (the port is ours)
        lib.fap_port_close(port)

    def _fd(self, port: Any) -> int:
        return int(lib.fap_port_fd(port))

    def close(self) -> None:
        """Close the port (idempotent). A receive() running in another
        thread ends with ClosedError within a fraction of a second."""
        super().close()

    def reopen(self) -> None:
        """Open the device again after it vanished (a USB unplug: ``receive``/``send``
        raised PortGoneError): the same path, line options and lock
        (``fap_port_reopen``), the half-read frame dropped. Raises PortError while
        the device is still away."""
        with self._lock, self._tx_lock:
            r = int(self._call(lib.fap_port_reopen))
            if r == 0:
                self._call(lambda _h: lib.mikrocRS485_CtxResetRx(self._ctx))
        if r < 0:
            raise error_from_code(r, "reopen", self.path)

    def _c_stats(self) -> Any:
        st = ffi.new("mikrocRS485_stats *")
        self._call(lambda _h: lib.mikrocRS485_CtxGetStats(self._ctx, st))
        return st

    @property
    def stats(self) -> NodeStats:
        """A snapshot of the counters (``mikrocRS485_stats``)."""
        return stats_from_c(NodeStats, self._c_stats())

    def _send(self, data: bytes, address: int) -> None:
        with self._tx_lock:
            r = self._call(lambda _h: lib.mikrocRS485_CtxSend(self._ctx, data, len(data), address))
        if r < 0:
            raise error_from_code(r, "send", self.path)

    def _poll(self, buf: Any, ms: int) -> int:
        """CtxPoll in slices, so that close() from another thread is seen."""
        end = None if ms < 0 else time.monotonic() + ms / 1000.0
        while True:
            r = self._call(lambda _h: lib.mikrocRS485_CtxPoll(self._ctx, buf, slice_ms(end)))
            if r != 0 or (end is not None and time.monotonic() >= end):
                return int(r)

    def _result(self, r: int, buf: Any, timeout: Optional[float], from_master: bool) -> Message:
        """The Message (or the exception) for a CtxPoll result."""
        if r == 0:
            raise FapTimeoutError(f"{self.path}: no mikroC frame within {timeout} s")
        if r < 0:
            raise error_from_code(r, "receive", self.path)
        if r & lib.MIKROC_RS485_POLL_ERROR:
            err = _frame_error(self._c_stats().last_rx_error)
            log.debug("%s: %s", self.path, err)
            raise err
        raw = bytes(ffi.buffer(buf, self._buffer_size))
        msg = Message(self._frame_address(raw), raw[0:raw[lib.MIKROC_RS485_IDX_COUNT]], from_master)
        log.debug("%s: rx %s", self.path, msg)
        return msg

    def _receive(self, timeout: Optional[float], from_master: bool) -> Message:
        ms = _timeout_ms(timeout)
        with self._lock:
            buf = ffi.new("char[]", self._buffer_size)   # fresh: flags cleared
            return self._result(self._poll(buf, ms), buf, timeout, from_master)

    async def _areceive(self, timeout: Optional[float], from_master: bool) -> Message:
        t = check_timeout(timeout)
        deadline = deadline_of(t)
        buf = ffi.new("char[]", self._buffer_size)
        while True:
            # Bytes the context already read are fed first; then the fd.
            with self._lock:
                r = int(self._call(lambda _h: lib.mikrocRS485_CtxPoll(self._ctx, buf, 0)))
            if r != 0:
                return self._result(r, buf, timeout, from_master)
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return self._result(0, buf, timeout, from_master)
            await self.await_readable(left)

    def _frame_address(self, raw: bytes) -> int:
        """The address of the frame just received (the master's buffer holds it)."""
        return raw[lib.MIKROC_RS485_IDX_ADDRESS]
