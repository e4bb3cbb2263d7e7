"""The exec async slave on a port (the C slave engine, a Python handler)."""
from __future__ import annotations

import errno
import logging
import os
import threading
import time
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Callable, Optional, Union

from .. import _trace  # wire bytes on fap_py.wire.exec at DEBUG
from .._handle import NativeHandle, deadline_of
from .._interruptible import open_interruptibly
from .._native import ffi, lib
from .._validate import check_bytes, check_path, check_seconds, timeout_ms
from ..errors import ClosedError
from ..rs485 import RS485, port_options  # the line options every fap_py node takes
from .codec import (
    BROADCAST,
    BytesLike,
    _check_node,
)
from .errors import (
    _ERR,
    ExecTypeError,
    _raise_for,
)
from .node import SlaveStats, _reopen, _stats

__all__ = ["Handler", "Request", "ServeResult", "Slave"]   # not the C callback below

log = logging.getLogger("fap_py.execasync")   # one logger for the package (as before the split)


@dataclass(frozen=True)
class Request:
    """A request as a :class:`Slave` handler sees it."""

    node: int          # the slave's node, or BROADCAST
    seq: int
    data: bytes

    @property
    def broadcast(self) -> bool:
        return self.node == BROADCAST


class ServeResult(IntEnum):
    """What one :meth:`Slave.serve` call did."""

    TIMEOUT = 0
    PROCESSED = lib.EXEC_SLAVE_PROCESSED   # the handler ran and its reply was sent
    RESENT = lib.EXEC_SLAVE_RESENT         # a retry: the last reply was sent again
    BROADCAST = lib.EXEC_SLAVE_BROADCAST   # the handler ran, nothing was sent


Handler = Callable[[Request], Optional[BytesLike]]

def _callback_failed(exc_type: Any, exc: Any, tb: Any) -> int:
    """Last resort if the trampoline itself fails: no reply, and say why."""
    log.error("exec async slave callback failed", exc_info=(exc_type, exc, tb))
    return -1


@ffi.def_extern(onerror=_callback_failed)
def fap_py_exec_slave_handler(ctx: Any, req: Any, reply: Any, cap: int) -> int:
    """C -> Python trampoline, called in the thread that runs execSlaveServe."""
    slave: Slave = ffi.from_handle(ctx)
    return slave._dispatch(req, reply, cap)


class Slave(NativeHandle):
    """Exec async slave for ``node`` (1..254) on one port.

    ``handler(request)`` returns the reply bytes (0..255), or ``None`` for
    no reply; it is not called again for a retried request (the last reply
    is resent) and is called for broadcasts, whose reply is ignored. Call
    :meth:`serve` from your own thread, :meth:`start` a background thread,
    or run :meth:`aserve` / :meth:`aserve_forever` in an asyncio loop (the
    port's fd drives it through ``loop.add_reader``; no thread; the handler
    then runs in the loop's thread). An exception in the handler sends no
    reply and is re-raised by :meth:`serve` (or kept in :attr:`error` by the
    background thread).

    Args:
        port, baudrate, rs485: as for :class:`Master`;
            ``rs485.turnaround_us`` delays every reply (for slow masters).
        node: this slave's node number, 1..254.
        handler: ``handler(request) -> bytes | None``.
    """

    _kind = "exec async slave"

    def __init__(self, port: Union[str, "os.PathLike[str]"], baudrate: int = 115200, *,
                 node: int, handler: Handler, rs485: Optional[RS485] = None) -> None:
        super().__init__()
        self._thread: Optional[threading.Thread] = None
        self._serve_lock = threading.Lock()   # one serve() at a time (C state)
        _check_node(node)
        if not callable(handler):
            raise ExecTypeError("handler must be callable")
        self.path = check_path(port)
        self.node = node
        self._handler = handler
        self._pending_error: Optional[BaseException] = None
        self.error: Optional[BaseException] = None
        popts = port_options(baudrate, rs485)
        sopts = ffi.new("execSlaveOptions *")
        lib.execSlaveOptionsInit(sopts)
        sopts.node = node
        self._self_handle = ffi.new_handle(self)
        out = ffi.new("execSlave **")
        raw = os.fsencode(self.path)

        def open_with(cancel_fd: int) -> int:   # a network open: Ctrl-C ends it (sopts.cancel_fd)
            sopts.cancel_fd = cancel_fd
            return int(lib.execSlaveOpen(out, raw, popts, sopts,
                                         lib.fap_py_exec_slave_handler, self._self_handle))

        _raise_for(open_interruptibly(raw, open_with,
                                      lambda rc: rc == 0 and lib.execSlaveClose(out[0])),
                   "open", self.path)
        self._adopt(out[0])
        self._tap = _trace.attach(lib.execSlaveSetTrace, self._h, "exec", self.path)
        log.info("exec async slave %d on %s", node, self.path)

    def _label(self) -> str:
        return f"exec async slave {self.node} on {self.path}"

    def _interrupt(self) -> None:
        # execSlaveStop is one eventfd write: serve() calls in other threads return at once
        self.stop()

    def _release(self, h: Any) -> None:
        lib.execSlaveClose(h)

    def _fd(self, h: Any) -> int:
        return int(lib.fap_port_fd(lib.execSlavePort(h)))

    def _dispatch(self, req: Any, reply: Any, cap: int) -> int:
        try:
            request = Request(int(req.node), int(req.seq), bytes(ffi.buffer(req.data, req.len)))
            if log.isEnabledFor(logging.DEBUG):
                log.debug("slave %d <- seq %d %s", self.node, request.seq, request.data.hex())
            out = self._handler(request)
            if out is None or request.broadcast:
                return -1
            out = check_bytes(out, "handler reply", 0, cap, **_ERR)
        except BaseException as exc:  # handed to serve(); C must not unwind through Python
            self._pending_error = exc
            return -1
        ffi.memmove(reply, out, len(out))
        if log.isEnabledFor(logging.DEBUG):
            log.debug("slave %d -> seq %d %s", self.node, request.seq, out.hex())
        return len(out)

    def _serve_c(self, ms: int) -> int:
        """One execSlaveServe call; the handler's exception re-raised."""
        with self._serve_lock:
            rc = int(self._call(lib.execSlaveServe, ms))
            err, self._pending_error = self._pending_error, None
        if err is not None:
            raise err
        if rc == -errno.ECANCELED:
            raise self._closed_error()
        _raise_for(rc, f"slave {self.node}", self.path)
        return rc

    def serve(self, timeout: Optional[float] = None) -> ServeResult:
        """Handle one request for this node (or a broadcast); wait at most
        ``timeout`` seconds (None = until one comes or :meth:`stop`)."""
        return ServeResult(self._serve_c(timeout_ms(timeout, **_ERR)))

    async def aserve(self, timeout: Optional[float] = None) -> ServeResult:
        """``await``-able :meth:`serve`: waits on the port fd with
        ``loop.add_reader`` (no thread), handles what arrived without blocking."""
        t = None if timeout is None else check_seconds(timeout, "timeout", **_ERR)
        deadline = deadline_of(t)
        while True:
            rc = self._serve_c(0)              # bytes already read first, then the fd
            if rc != 0:
                return ServeResult(rc)
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return ServeResult.TIMEOUT
            await self.await_readable(left)

    async def aserve_forever(self) -> None:
        """Serve requests until the slave is closed (then return)."""
        try:
            while True:
                await self.aserve(None)
        except ClosedError:
            return

    def _run(self) -> None:
        try:
            while True:
                self.serve(None)
        except ClosedError:
            pass
        except BaseException as exc:  # kept for the owner; the thread ends
            log.exception("slave %d on %s stopped", self.node, self.path)
            self.error = exc

    def start(self) -> "Slave":
        """Serve in a background (daemon) thread until :meth:`stop` / :meth:`close`."""
        with self._serve_lock:
            if self.closed:
                raise self._closed_error()
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=f"exec-slave-{self.node}",
                                                daemon=True)
                self._thread.start()
        return self

    def stop(self) -> None:
        """Make serve() return (raising ClosedError) now and from then on; join the thread."""
        h = self._h
        if h is not None:
            lib.execSlaveStop(h)
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def reopen(self) -> None:
        """Open the device again after it vanished (serve() raised PortError)."""
        _reopen(self, lib.execSlavePort)

    @property
    def stats(self) -> SlaveStats:
        """A snapshot of the counters (``execSlaveStats``)."""
        return _stats(self, SlaveStats, "execSlaveStats *", lib.execSlaveGetStats)

    def close(self) -> None:
        """Stop serving (also serve() calls in other threads) and close the port. Idempotent."""
        super().close()
