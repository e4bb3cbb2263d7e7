"""What the FAP master and slave share: one C engine (a libfap handle) on one port;
the argument checks and the message path's C calls."""
from __future__ import annotations

import errno as _errno
import logging
import math
import os
import threading
import time
from asyncio import get_running_loop as _running_loop
from typing import Any, AsyncIterator, Iterator, List, Optional, Union

from .._handle import WAIT_SLICE, NativeHandle, deadline_of, slice_ms
from .._interruptible import open_interruptibly
from .._native import ffi as _ffi
from .._native import lib as _lib
from .._stats import stats_from_c
from .._validate import MAX_TIMEOUT, check_baud, check_bytes, check_int, check_path, check_seconds
from ..errors import (
    ClosedError,
    FapError,
    FapTimeoutError,
    InvalidTypeError,
    InvalidValueError,
    NotMasterError,
    PortError,
    QueueFullError,
    SlaveExistsError,
    UnknownSlaveError,
    error_from_code,
)
from ..rs485 import RS485, RS485Mode, line_options
from .aio import AsyncMessages, AsyncPump
from .types import (
    MAX_DATA,
    MAX_ID,
    EventKind,
    Message,
    SlaveEvent,
    Stats,
    _new_message,
)

log = logging.getLogger(__name__)

PathLike = Union[str, bytes, "os.PathLike[str]", "os.PathLike[bytes]"]
#: Longest protocol timing fapx_options holds without overflow in the engine (µs).
_TIMING_US_MAX = 1 << 62


def _error(code: int, what: str, path: Optional[str] = None, detail: str = "") -> FapError:
    """The exception for a negative ``fapx_*`` return code."""
    extra = f" ({detail})" if detail else ""
    err = -code
    if err == _errno.EINVAL:
        return InvalidValueError(f"{what}: invalid argument{extra}")
    if err == _errno.EPERM:
        return NotMasterError(f"{what}: only a master keeps a slave list{extra}")
    if err == _errno.EEXIST:
        return SlaveExistsError(f"{what}: slave already listed{extra}")
    if err == _errno.ENOENT and what != "open":
        return UnknownSlaveError(f"{what}: slave not listed{extra}")
    if err == _errno.EAGAIN:
        return QueueFullError(f"{what}: transmit queue full{extra}; flush() or retry later")
    if err == _errno.ETIMEDOUT:
        if what == "open":   # no connection within connect_ms (tcp://, rfc2217://): a port error
            return PortError(err, "open: connection timed out", path)
        return FapTimeoutError(f"{what}: timed out{extra}")
    if err == _errno.ESHUTDOWN:
        return ClosedError(f"{what}: the node is closed")
    if err == _errno.EMSGSIZE:  # pragma: no cover - our buffers hold MAX_DATA
        return FapError(f"{what}: receive buffer too small")
    return error_from_code(code, what, path)


# -- argument checks (before anything reaches C) -----------------------------

def _int(value: Any, what: str, lo: int, hi: int) -> int:
    return check_int(value, what, lo, hi)


def _slave_id(value: Any, what: str = "slave id") -> int:
    return _int(value, what, 1, MAX_ID)


def _payload(data: Any) -> bytes:
    return check_bytes(data, "data", 1, MAX_DATA)


def _seconds(value: Any, what: str) -> float:
    return check_seconds(value, what)


def _timing_us(value: Optional[float], what: str) -> int:
    """Protocol timing in seconds -> µs for fapx_options (None -> 0 = C default)."""
    if value is None:
        return 0
    s = check_seconds(value, what, lo=0.0, lo_open=True, hi=_TIMING_US_MAX / 1e6)
    return max(1, math.ceil(s * 1e6))


def _deadline(timeout: Optional[float]) -> Optional[float]:
    return deadline_of(None if timeout is None else _seconds(timeout, "timeout"))


#: A whole WAIT_SLICE in ms: the slice of a wait without a deadline.
_SLICE_MS = slice_ms(None)


def _slice_ms(deadline: Optional[float]) -> int:
    """Milliseconds for the next wait inside C: at most WAIT_SLICE."""
    return slice_ms(deadline)


def _first_wait(timeout: Optional[float]) -> "tuple[Optional[float], int]":
    """(deadline, ms of the first wait inside C) of a blocking call's ``timeout``.

    The hot path of recv() and send(): a plain int or float in range is taken as
    it is (no call to the general check, no clock arithmetic beyond one
    ``monotonic()``); anything else (bool, NaN, inf, negative, too long, a
    string) goes through the general check, which raises the specific error.
    """
    if timeout is None:
        return None, _SLICE_MS
    if not ((type(timeout) is float or type(timeout) is int) and 0 <= timeout <= MAX_TIMEOUT):
        timeout = _seconds(timeout, "timeout")
    first = _SLICE_MS if timeout >= WAIT_SLICE else math.ceil(timeout * 1000)
    return time.monotonic() + timeout, first


# The C calls of the message path, looked up once (each is an attribute lookup
# on the cffi module otherwise): a round trip runs four of them.
_fapx_tx, _fapx_tx_wait = _lib.fapx_tx, _lib.fapx_tx_wait
_fapx_rx, _fapx_rx_wait = _lib.fapx_rx, _lib.fapx_rx_wait
_unpack = _ffi.unpack
_ETIMEDOUT, _EAGAIN = -_errno.ETIMEDOUT, -_errno.EAGAIN
_DEBUG = logging.DEBUG


# -- nodes --------------------------------------------------------------------


class Node(NativeHandle, AsyncMessages):
    """What masters and slaves share: one C engine on one serial port.

    Not instantiated directly: use :class:`Master` or :class:`Slave`. A node
    is a context manager (sync and async) that closes it; every method is
    thread-safe. Closing makes every later call raise :class:`ClosedError`.
    """

    _mode: int = -1
    _dests: "frozenset[int]" = frozenset()   # valid send() destinations (subclasses)

    def __init__(self, port: PathLike, baudrate: int = 115200, *, node_id: int,
                 id_cycle: Optional[float] = None,
                 id_answer_timeout: Optional[float] = None,
                 data_done_timeout: Optional[float] = None,
                 send_budget: Optional[float] = None,
                 byte_gap: Optional[float] = None,
                 reopen_interval: Optional[float] = None,
                 rx_queue: Optional[int] = None,
                 tx_queue: Optional[int] = None,
                 event_queue: Optional[int] = None,
                 rs485: Optional[RS485] = None) -> None:
        super().__init__()
        if self._mode < 0:
            raise InvalidTypeError("Node is the base of Master and Slave: open one of those")
        self._lock = self._hlock             # one lock: handle users, stash, pump
        self._pump: Optional[AsyncPump] = None
        self._stash: List[SlaveEvent] = []   # events taken by wait_active, not yet read
        self._tls = threading.local()        # per-thread receive buffers
        #: the counters at close (``tx_abandoned``: output the close dropped); None while open
        self.final_stats: Optional[Stats] = None
        self.path: str = check_path(port)      #: the serial device
        self.baudrate: int = check_baud(baudrate)
        self.id: int = node_id                 #: this node's FAP ID (master 0)
        self.rs485: RS485 = line_options(rs485)   #: the RS-485 options asked for
        ffi, lib = _ffi, _lib
        self._ffi, self._lib = ffi, lib
        opts = ffi.new("fapx_options *")
        lib.fapx_options_init(opts)
        opts.mode = self._mode
        opts.id = node_id
        opts.idc_us = _timing_us(id_cycle, "id_cycle")
        opts.id_answer_us = _timing_us(id_answer_timeout, "id_answer_timeout")
        opts.data_done_us = _timing_us(data_done_timeout, "data_done_timeout")
        opts.send_budget_us = _timing_us(send_budget, "send_budget")
        opts.gap_us = _timing_us(byte_gap, "byte_gap")
        opts.reopen_us = _timing_us(reopen_interval, "reopen_interval")
        for name, value, attr in (("rx_queue", rx_queue, "rx_depth"),
                                  ("tx_queue", tx_queue, "tx_depth"),
                                  ("event_queue", event_queue, "ev_depth")):
            if value is not None:
                setattr(opts, attr, _int(value, name, 1, 1 << 20))
        self._rx_depth = opts.rx_depth or lib.FAPX_DEFAULT_RX_DEPTH
        self._ev_depth = opts.ev_depth or lib.FAPX_DEFAULT_EV_DEPTH
        self.rs485.apply_to(lib.fapx_options_port(opts), self.baudrate)  # &opts->port (opaque to cffi)
        from .. import _trace
        self._tap = _trace.tap_for("fap", self.path)   # wire bytes at DEBUG (fap_py/_trace.py)
        if self._tap is not None:                      # set before open: sees the first frame
            opts.trace, opts.trace_ctx = lib.fap_py_trace, self._tap.handle
        out = ffi.new("fapx **")
        raw = os.fsencode(self.path)

        def open_with(cancel_fd: int) -> int:   # a network open: Ctrl-C ends it (opts.cancel_fd)
            opts.cancel_fd = cancel_fd
            return int(lib.fapx_open(out, raw, opts))

        code = open_interruptibly(raw, open_with, lambda rc: rc == 0 and lib.fapx_close(out[0]))
        if code < 0:
            raise _error(code, "open", self.path,
                         ffi.string(lib.fapx_strerror(code)).decode(errors="replace"))
        self._adopt(out[0])
        log.info("%s open on %s at %d baud (RS-485 %s)", self._label(), self.path,
                 self.baudrate, self.rs485_mode.name)

    # -- lifetime (NativeHandle) ------------------------------------------
    def _label(self) -> str:
        return "master" if self._mode == 0 else f"slave {self.id}"

    def _closed_error(self) -> ClosedError:
        return ClosedError(f"{self._label()} on {self.path} is closed")

    def _interrupt(self) -> None:
        pump, self._pump = self._pump, None
        if pump is not None:
            pump.stop()

    def _release(self, h: Any) -> None:
        st = self._ffi.new("fapx_stats *")
        self._lib.fapx_close_stats(h, st)   # joins the engine thread (GIL released)
        self.final_stats = stats_from_c(Stats, st)
        # INFO, not a warning: closing with data still queued is an ordinary choice
        log.info("%s on %s closed (%d queued frame(s) dropped: tx_abandoned)", self._label(),
                 self.path, st.tx_abandoned)

    def _fd(self, h: Any) -> int:
        return int(self._lib.fapx_notify_fd(h))

    def close(self) -> None:
        """Stop the engine and close the port. Idempotent; ends within 0.5 s
        whatever the line does.

        Threads blocked in :meth:`recv` / :meth:`wait_event` / :meth:`flush` /
        :meth:`send` raise :class:`ClosedError` (within :data:`WAIT_SLICE`);
        pending asyncio waiters get :class:`ClosedError` too. A write the line
        does not take within 0.1 s is abandoned; :attr:`final_stats` (the
        counters at close) counts it and the DATA still queued in
        ``tx_abandoned``.
        """
        super().close()

    def __repr__(self) -> str:
        state = "closed" if self._closing else "open"
        return f"<{type(self).__name__} id={self.id} {self.path} {self.baudrate} baud {state}>"

    # -- information ----------------------------------------------------
    @property
    def rs485_mode(self) -> RS485Mode:
        """The RS-485 direction mode actually in force (never AUTO)."""
        lib = self._lib
        return RS485Mode(self._call(lambda h: lib.fap_port_mode(lib.fapx_port(h))))

    @property
    def stats(self) -> Stats:
        """A snapshot of the engine's counters (:class:`~fap_py._stats.Counters`)."""
        st = self._ffi.new("fapx_stats *")
        self._call(self._lib.fapx_get_stats, st)
        return stats_from_c(Stats, st)

    @property
    def rx_pending(self) -> int:
        """Received messages queued in C, not read yet."""
        n = int(self._call(self._lib.fapx_rx_pending))
        pump = self._pump
        return n + (pump.rx_queued() if pump is not None else 0)

    @property
    def tx_pending(self) -> int:
        """Messages queued by :meth:`send` and not on the wire yet."""
        return int(self._call(self._lib.fapx_tx_pending))

    # -- sending ----------------------------------------------------------
    def _check_dest(self, to: Any) -> int:
        raise NotImplementedError

    def send(self, data: Union[bytes, bytearray, memoryview], to: int,
             timeout: Optional[float] = 0.0) -> None:
        """Queue ``data`` (1..1024 bytes) for node ``to``; it goes out in this node's turn.

        Args:
            timeout: how long to wait for room when the transmit queue is
                full: 0 (default) raises at once, ``None`` waits as long as
                it takes.

        Raises:
            InvalidValueError / InvalidTypeError: bad ``data`` or ``to``
                (checked before anything reaches C).
            QueueFullError: the transmit queue is (still) full.
            ClosedError: the node is (or got) closed.
        """
        # Hot path: an int destination already known valid and a bytes payload
        # skip the general checks (which raise the specific errors otherwise).
        dest = to if type(to) is int and to in self._dests else self._check_dest(to)
        payload = data if type(data) is bytes and 0 < len(data) <= MAX_DATA else _payload(data)
        if timeout == 0.0:
            code = self._call(_fapx_tx, dest, payload, len(payload))
        else:
            deadline, wait_ms = _first_wait(timeout)
            while True:
                code = self._call(_fapx_tx_wait, dest, payload, len(payload), wait_ms)
                if code != _ETIMEDOUT:
                    break
                if deadline is not None:
                    if time.monotonic() >= deadline:
                        code = _EAGAIN           # still full: QueueFullError
                        break
                    wait_ms = _slice_ms(deadline)
        if code < 0:
            raise _error(code, "send")
        if log.isEnabledFor(_DEBUG):
            log.debug("%s: queued %d bytes for %d", self._label(), len(payload), dest)

    def flush(self, timeout: Optional[float] = None) -> None:
        """Wait until everything :meth:`send` queued is on the wire.

        Raises:
            FapTimeoutError: ``timeout`` seconds passed first.
        """
        deadline = _deadline(timeout)
        while True:
            code = self._call(self._lib.fapx_flush, _slice_ms(deadline))
            if code == 0:
                return
            if code != -_errno.ETIMEDOUT or (deadline is not None
                                             and time.monotonic() >= deadline):
                raise _error(code, "flush")

    # -- receiving ----------------------------------------------------------
    def recv_nowait(self) -> Optional[Message]:
        """The oldest received message, or None if none is queued."""
        pump = self._pump
        if pump is not None:
            msg = pump.take_rx()
            if msg is not None:
                return msg
        return self._rx_c(None)

    def _rx_c(self, wait_ms: Optional[int]) -> Optional[Message]:
        """One fapx_rx / fapx_rx_wait call: a message, or None on -EAGAIN/-ETIMEDOUT."""
        try:
            buf, src = self._tls.rx
        except AttributeError:       # first receive in this thread: its own buffers
            buf, src = self._tls.rx = (_ffi.new("char[]", MAX_DATA), _ffi.new("unsigned *"))
        if wait_ms is None:
            n = self._call(_fapx_rx, buf, MAX_DATA, src)
        else:
            n = self._call(_fapx_rx_wait, buf, MAX_DATA, src, wait_ms)
        if n >= 0:
            msg = _new_message(src[0], _unpack(buf, n))   # char[]: unpack gives bytes
            if log.isEnabledFor(_DEBUG):   # per message: no label built for nothing
                log.debug("%s: received %d bytes from %d", self._label(), n, msg.source)
            return msg
        if n == _EAGAIN or n == _ETIMEDOUT:
            return None
        raise _error(n, "recv")

    def recv(self, timeout: Optional[float] = None) -> Message:
        """Wait for the next message addressed to this node.

        Args:
            timeout: seconds to wait; ``None`` waits until a message comes
                or the node is closed.

        Raises:
            FapTimeoutError: nothing arrived within ``timeout``.
            ClosedError: the node is (or got) closed.
            KeyboardInterrupt: Ctrl-C while waiting.
        """
        deadline, wait_ms = _first_wait(timeout)
        while True:
            pump = self._pump
            if pump is not None:
                msg = pump.take_rx()
                if msg is not None:
                    return msg
            msg = self._rx_c(wait_ms)
            if msg is not None:
                return msg
            if deadline is not None:
                if time.monotonic() >= deadline:
                    raise FapTimeoutError(f"recv: no message within {timeout} s")
                wait_ms = _slice_ms(deadline)

    def __iter__(self) -> Iterator[Message]:
        """Received messages, forever; the iteration ends when the node is closed."""
        try:
            while True:
                yield self.recv()
        except ClosedError:
            return

    def messages(self, timeout: Optional[float] = None) -> Iterator[Message]:
        """Received messages until none arrives for ``timeout`` seconds (or close)."""
        try:
            while True:
                yield self.recv(timeout)
        except (FapTimeoutError, ClosedError):
            return

    # -- events ------------------------------------------------------------
    def _ev_c(self, wait_ms: Optional[int]) -> Optional[SlaveEvent]:
        try:
            ev = self._tls.ev
        except AttributeError:       # first event read in this thread: its own buffer
            ev = self._tls.ev = self._ffi.new("fapx_event *")
        if wait_ms is None:
            code = self._call(self._lib.fapx_event_get, ev)
        else:
            code = self._call(self._lib.fapx_event_wait, ev, wait_ms)
        if code == 0:
            try:
                kind = EventKind(ev.type)
            except ValueError:  # pragma: no cover - a newer engine's event
                log.warning("%s: unknown event type %d", self._label(), ev.type)
                return None
            out = SlaveEvent(kind, int(ev.id), int(ev.time_ns))
            log.debug("%s: event %s", self._label(), out)
            return out
        if code in (-_errno.EAGAIN, -_errno.ETIMEDOUT):
            return None
        raise _error(code, "event")

    def _take_stashed(self) -> Optional[SlaveEvent]:
        """The oldest event wait_active took and kept, if any."""
        with self._lock:
            return self._stash.pop(0) if self._stash else None

    def _next_event(self, wait_ms: Optional[int]) -> Optional[SlaveEvent]:
        ev = self._take_stashed()
        if ev is not None:
            return ev
        pump = self._pump
        if pump is not None:
            ev = pump.take_event()
            if ev is not None:
                return ev
        return self._ev_c(wait_ms)

    def wait_event(self, timeout: Optional[float] = None) -> SlaveEvent:
        """Wait for the next engine event (slave active/inactive, port lost...).

        Raises:
            FapTimeoutError: none within ``timeout`` seconds.
            ClosedError: the node is (or got) closed.
        """
        deadline = _deadline(timeout)
        while True:
            ev = self._next_event(_slice_ms(deadline))
            if ev is not None:
                return ev
            if deadline is not None and time.monotonic() >= deadline:
                raise FapTimeoutError(f"wait_event: no event within {timeout} s")

    def events(self, timeout: Optional[float] = 0.0) -> Iterator[SlaveEvent]:
        """Engine events until none comes for ``timeout`` seconds.

        ``timeout=0`` (the default) yields only what is queued now;
        ``None`` waits for events until the node is closed.
        """
        try:
            while True:
                yield self.wait_event(timeout)
        except (FapTimeoutError, ClosedError):
            return

    # -- asyncio -------------------------------------------------------------
    def _aio(self) -> AsyncPump:
        with self._lock:
            if self._closing:
                raise self._closed_error()
            pump = self._pump
        pump = AsyncPump.for_running_loop(self, pump)
        with self._lock:
            if self._closing:
                pump.stop()
                raise self._closed_error()
            self._pump = pump
        return pump

    async def arecv(self, timeout: Optional[float] = None) -> Message:
        """``await``-able :meth:`recv`, driven by the notification fd (no thread, no polling)."""
        if timeout is not None:
            timeout = _seconds(timeout, "timeout")
        pump = self._pump
        if pump is None or pump.stopped or self._closing or pump.loop is not _running_loop():
            pump = self._aio()       # attach (or re-attach) to this loop; raises once closed
        msg = pump.take_rx()         # already moved to Python: no future, no coroutine
        if msg is not None:
            return msg
        return await pump.get_rx(timeout)


    async def await_event(self, timeout: Optional[float] = None) -> SlaveEvent:
        """``await``-able :meth:`wait_event`."""
        if timeout is not None:
            _seconds(timeout, "timeout")
        ev = self._take_stashed()
        if ev is not None:
            return ev
        return await self._aio().get_event(timeout)

    async def aevents(self, timeout: Optional[float] = None) -> AsyncIterator[SlaveEvent]:
        """``async for ev in node.aevents()``: events until none for ``timeout`` s / close."""
        try:
            while True:
                yield await self.await_event(timeout)
        except (FapTimeoutError, ClosedError):
            return

    async def aclose(self) -> None:
        """Close from a coroutine: detach from the event loop, then close in a worker thread."""
        pump = self._pump
        if pump is not None:
            pump.stop()
        await super().aclose()
