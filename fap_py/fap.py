"""FAP (Fast Action Protocol) master and slave nodes, run by libfap's C engine.

Each :class:`Master` or :class:`Slave` owns one handle of libfap's re-entrant
API (``include/fapx.h``): a C engine thread that talks to the serial port,
keeps the protocol's timers and queues the frames and events. Python code
gets exactly the engine C programs get; this module only converts types,
checks arguments and turns C error codes into exceptions.

Example::

    from fap_py import Master, Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2) as bus, \\
         Master(bus.paths[0], 115200, slaves=[7], id_cycle=0.05) as master, \\
         Slave(bus.paths[1], 115200, id=7) as slave:
        master.wait_active([7], timeout=2)
        master.send(b"hello", to=7)
        print(slave.recv(timeout=2))         # Message(source=0, data=b'hello')

Blocking calls (:meth:`Node.recv`, :meth:`Node.wait_event`, ...) release the
GIL while they wait and wait in slices of :data:`WAIT_SLICE` seconds inside
C, so Ctrl-C (``KeyboardInterrupt``) and :meth:`Node.close` from another
thread take effect within one slice. The asyncio methods
(:meth:`Node.arecv`, ``async for``, :meth:`Node.aevents`) are driven by the
engine's notification fd through ``loop.add_reader`` (see
:mod:`fap_py.fap_aio`).
"""
from __future__ import annotations

import enum
import errno as _errno
import logging
import math
import os
import threading
import time
from dataclasses import dataclass, fields
from typing import (TYPE_CHECKING, Any, AsyncIterator, Callable, Dict, Iterable, Iterator,
                    List, Optional, Tuple, Union)

from ._util import Closing, check_int, from_cdata, slice_ms
from .errors import (ClosedError, FapError, FapTimeoutError, InvalidValueError,
                     NotInitialisedError, QueueFullError, error_from_code)

if TYPE_CHECKING:  # pragma: no cover
    from .fap_aio import AsyncPump

__all__ = [
    "MASTER_ID",
    "MAX_DATA",
    "MAX_ID",
    "WAIT_SLICE",
    "classic_check",
    "EventKind",
    "InvalidTypeError",
    "Master",
    "Message",
    "Node",
    "NotMasterError",
    "RS485",
    "RS485Mode",
    "Slave",
    "SlaveEvent",
    "SlaveExistsError",
    "Stats",
    "UnknownSlaveError",
]

log = logging.getLogger(__name__)

MASTER_ID = 0          #: the master's ID (fixed by the protocol)
MAX_ID = 31            #: slave IDs are 1..MAX_ID (FAPX_MAX_ID)
MAX_DATA = 1024        #: bytes per DATA frame (FAPX_MAX_DATA)
#: Longest single wait inside C (seconds): the latency of Ctrl-C and of a
#: close() from another thread while a blocking call waits.
WAIT_SLICE = 0.1

_U32 = 0xFFFFFFFF
_INT_MS_MAX = 0x7FFFFFFF
PathLike = Union[str, bytes, "os.PathLike[str]", "os.PathLike[bytes]"]

_native_mod: Optional[Tuple[Any, Any]] = None


def _native() -> Tuple[Any, Any]:
    """(ffi, lib) of the extension, imported on first use."""
    global _native_mod
    if _native_mod is None:
        from ._native import ffi, lib

        if ((lib.FAPX_MAX_ID, lib.FAPX_MAX_DATA) != (MAX_ID, MAX_DATA) or
                (lib.GOOD, lib.BAD, lib.E_PARAM, lib.E_VALUE, lib.E_INIT, lib.E_RES)
                != (0, 1, 2, 3, 4, 5)):  # pragma: no cover
            raise FapError("fap_py.fap and the compiled libfap disagree on FAP constants")
        _native_mod = (ffi, lib)
    return _native_mod


# -- errors -----------------------------------------------------------------

class InvalidTypeError(InvalidValueError, TypeError):
    """An argument has the wrong type (also a ``TypeError``)."""


class NotMasterError(InvalidValueError):
    """A slave-list operation was asked of a slave node (C: -EPERM)."""


class SlaveExistsError(InvalidValueError):
    """add_slave: the slave is already listed (C: -EEXIST)."""


class UnknownSlaveError(InvalidValueError):
    """The slave is not listed on this master (C: -ENOENT)."""


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
        return FapTimeoutError(f"{what}: timed out{extra}")
    if err == _errno.ESHUTDOWN:
        return ClosedError(f"{what}: the node is closed")
    if err == _errno.EMSGSIZE:  # pragma: no cover - our buffers hold MAX_DATA
        return FapError(f"{what}: receive buffer too small")
    return error_from_code(code, what, path)


_CLASSIC_TEXT = {1: "BAD (port could not be opened, or baud rate not 9600..115200)",
                 2: "E_PARAM (wrong mode, or a slave-list call on a slave)",
                 3: "E_VALUE (ID or size out of range, slave listed twice or not listed)",
                 4: "E_INIT (fapInit/fapConfig not done, or the handle was closed)",
                 5: "E_RES (queue full or empty)"}


def classic_check(code: int, what: str) -> None:
    """Raise the exception for a vendor-API (``fap.h``) return code; GOOD passes.

    For Python code that calls the classic API through ``fap_py._native``:
    ``classic_check(lib.fapTx(data, len(data), 3), "fapTx")``. ``E_RES`` is
    :class:`QueueFullError` (from ``fapTx``; ``fapRx`` returns it for "nothing
    received", which callers test for before calling this).
    """
    if code == 0:
        return
    msg = f"{what}: {_CLASSIC_TEXT.get(code, f'unknown code {code}')}"
    if code in (2, 3):
        raise InvalidValueError(msg)
    if code == 4:
        raise NotInitialisedError(msg)
    if code == 5:
        raise QueueFullError(msg)
    raise FapError(msg)


# -- argument checks (before anything reaches C) -----------------------------

def _int(value: Any, what: str, lo: int, hi: int) -> int:
    return check_int(value, what, lo, hi, error=InvalidValueError, type_error=InvalidTypeError)


def _slave_id(value: Any, what: str = "slave id") -> int:
    return _int(value, what, 1, MAX_ID)


def _payload(data: Any) -> bytes:
    if type(data) is bytes and 1 <= len(data) <= MAX_DATA:   # the common case, fast
        return data
    if isinstance(data, str):
        raise InvalidTypeError("data must be bytes-like, not str (encode it first)")
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise InvalidTypeError(f"data must be bytes-like, not {type(data).__name__}")
    payload = bytes(data)
    if not 1 <= len(payload) <= MAX_DATA:
        raise InvalidValueError(f"data must hold 1..{MAX_DATA} bytes, not {len(payload)}")
    return payload


def _seconds(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidTypeError(f"{what} must be a number of seconds, not {type(value).__name__}")
    if math.isnan(value) or value < 0:
        raise InvalidValueError(f"{what} must be >= 0 seconds, not {value}")
    return float(value)


def _timing_us(value: Optional[float], what: str) -> int:
    """Protocol timing in seconds -> µs for fapx_options (None -> 0 = C default)."""
    if value is None:
        return 0
    s = _seconds(value, what)
    us = math.ceil(s * 1e6)
    if not 1 <= us <= 1 << 62:
        raise InvalidValueError(f"{what} must be > 0 and finite, not {value}")
    return us


def _deadline(timeout: Optional[float]) -> Optional[float]:
    if timeout is None:
        return None
    return time.monotonic() + _seconds(timeout, "timeout")


def _slice_ms(deadline: Optional[float]) -> int:
    """Milliseconds for the next wait inside C: at most WAIT_SLICE."""
    return slice_ms(deadline, int(WAIT_SLICE * 1000))


# -- value types -------------------------------------------------------------

class RS485Mode(enum.IntEnum):
    """How the transmitter is switched (``fap_rs485_mode``)."""

    AUTO = 0      #: kernel RS-485 if the driver has it, else NONE
    KERNEL = 1    #: TIOCSRS485: the kernel toggles RTS
    SOFT_RTS = 2  #: assert RTS, write, tcdrain(), release RTS
    NONE = 3      #: auto-direction transceiver, USB adapter, pty


@dataclass(frozen=True)
class RS485:
    """RS-485 line options of a node (``fap_port_options``).

    Times are integer microseconds, as the C layer takes them (the kernel
    rounds its RTS delays up to milliseconds).
    """

    mode: RS485Mode = RS485Mode.AUTO
    #: RTS pin level while sending (every mode); None: the device's own
    #: RS-485 config decides (FAP_PORT_KEEP), else high
    rts_active_high: Optional[bool] = None
    delay_before_send_us: Optional[int] = None  #: RTS to sending level -> first bit; None: the device's
    delay_after_send_us: Optional[int] = None   #: last bit -> RTS back; None: the device's
    rx_during_tx: Optional[bool] = None  #: kernel mode: receiver on while sending; None: the device's
    echo_suppression: bool = False   #: read back and drop our own bytes (2-wire adapters)
    echo_timeout_us: int = 0         #: wait for the echo; 0 = 20 char times + 20 ms
    turnaround_us: int = 0           #: quiet time after the last received byte before sending
    exclusive: bool = True           #: TIOCEXCL + flock: refuse a second opener
    write_timeout_us: int = 0        #: longest write; 0 = twice the wire time + 1 s

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "mode", RS485Mode(self.mode))
        except ValueError as exc:
            raise InvalidValueError(f"RS485.mode must be an RS485Mode, not {self.mode!r}") from exc
        keep = ("rts_active_high", "delay_before_send_us", "delay_after_send_us", "rx_during_tx")
        for name in ("delay_before_send_us", "delay_after_send_us", "echo_timeout_us",
                     "turnaround_us", "write_timeout_us"):
            if name not in keep:
                _int(getattr(self, name), f"RS485.{name}", 0, _U32)
            elif getattr(self, name) is not None:   # UINT_MAX is FAP_PORT_KEEP_DELAY
                _int(getattr(self, name), f"RS485.{name}", 0, _U32 - 1)
        for name in ("rts_active_high", "rx_during_tx", "echo_suppression", "exclusive"):
            if name in keep and getattr(self, name) is None:
                continue
            if not isinstance(getattr(self, name), bool):
                raise InvalidTypeError(f"RS485.{name} must be a bool")

    def apply_to(self, po: Any, baudrate: int) -> Any:
        """Fill a cffi ``fap_port_options *`` with ``baudrate`` and these options.

        The one place that maps Python line options onto the C port layer:
        every protocol binding (FAP, exec async, mikroC) opens its port
        through it.
        """
        po.baud = baudrate
        po.rs485_mode = int(self.mode)
        _, lib = _native()
        keep, keep_delay = lib.FAP_PORT_KEEP, lib.FAP_PORT_KEEP_DELAY
        po.rts_active_high = keep if self.rts_active_high is None else int(self.rts_active_high)
        po.delay_before_send_us = (keep_delay if self.delay_before_send_us is None
                                   else self.delay_before_send_us)
        po.delay_after_send_us = (keep_delay if self.delay_after_send_us is None
                                  else self.delay_after_send_us)
        po.rx_during_tx = keep if self.rx_during_tx is None else int(self.rx_during_tx)
        po.echo_suppression = int(self.echo_suppression)
        po.echo_timeout_us = self.echo_timeout_us
        po.turnaround_us = self.turnaround_us
        po.exclusive = int(self.exclusive)
        po.write_timeout_us = self.write_timeout_us
        return po


def _line_options(rs485: Optional[RS485]) -> RS485:
    """``rs485`` checked, ``None`` = the port layer's defaults."""
    if rs485 is None:
        return RS485()
    if not isinstance(rs485, RS485):
        raise InvalidTypeError(f"rs485 must be an RS485, not {type(rs485).__name__}")
    return rs485


def port_options(baudrate: int, rs485: Optional[RS485] = None) -> Any:
    """A new cffi ``fap_port_options *`` for ``baudrate`` and ``rs485``
    (``None`` = the port layer's defaults: direction mode AUTO, no echo
    suppression, exclusive). Raises before anything reaches C."""
    baudrate = _int(baudrate, "baudrate", 1, _U32)   # the same check as Node's
    rs485 = _line_options(rs485)
    ffi, lib = _native()
    po = ffi.new("fap_port_options *")
    lib.fap_port_options_init(po)
    return rs485.apply_to(po, baudrate)


class EventKind(enum.IntEnum):
    """What a :class:`SlaveEvent` reports (``fapx_event_type``)."""

    SLAVE_ACTIVE = 1    #: master: the slave answered QUERY_ID
    SLAVE_INACTIVE = 2  #: master: the slave missed DATA_DONE (an ID cycle follows)
    ID_TIMEOUT = 3      #: master: the slave did not answer QUERY_ID
    QUERIED = 4         #: slave: the master queried us (we answered)
    RX = 5              #: (C callback only; never queued)
    PORT_LOST = 6       #: the port failed; the engine retries to open it
    PORT_REOPENED = 7   #: the port is back
    RX_OVERFLOW = 8     #: a DATA frame from ``id`` was dropped: receive queue full


@dataclass(frozen=True)
class Message:
    """A DATA frame received by this node."""

    source: int   #: sender ID (0 = the master)
    data: bytes   #: 1..1024 bytes

    def __repr__(self) -> str:
        shown = self.data if len(self.data) <= 32 else self.data[:32]
        more = "" if len(self.data) <= 32 else f"...+{len(self.data) - 32}"
        return f"Message(source={self.source}, data={shown!r}{more})"


@dataclass(frozen=True)
class SlaveEvent:
    """An event from the engine: slave state changes, port loss and return."""

    kind: EventKind  #: what happened
    id: int          #: the slave (master events) or this node's ID (port/queried events)
    time_ns: int     #: CLOCK_MONOTONIC time of the event (``time.monotonic_ns()`` clock)

    @property
    def name(self) -> str:
        """The C name of the kind, e.g. ``slave-active``."""
        return self.kind.name.lower().replace("_", "-")

    def __str__(self) -> str:
        return f"{self.name} id={self.id}"


@dataclass(frozen=True)
class Stats:
    """Counters of a node since it opened (``fapx_stats``)."""

    frames_tx: int           #: valid frames sent (all types)
    frames_rx: int           #: valid frames received (all types, any destination)
    bytes_tx: int            #: wire bytes sent
    bytes_rx: int            #: wire bytes received
    data_tx: int             #: DATA frames sent
    data_rx: int             #: DATA frames delivered to this node
    crc_errors: int          #: complete frames with a bad CRC
    framing_errors: int      #: bad size, msg/size mismatch
    gap_timeouts: int        #: partial frames abandoned after the inter-byte gap
    garbage_bytes: int       #: bytes skipped while looking for a marker
    id_timeouts: int         #: master: QUERY_ID unanswered
    data_done_timeouts: int  #: master: DATA_DONE missing (slave marked inactive)
    collisions: int          #: echo mismatches reported by the port layer
    cycles: int              #: master: complete data cycles
    id_cycles: int           #: master: complete ID cycles
    polls: int               #: SEND_DATA -> DATA_DONE turns completed
    rx_dropped: int          #: DATA lost to a full receive queue
    tx_dropped: int          #: queued frames discarded
    write_errors: int        #: failed port writes
    port_lost: int           #: times the port failed
    port_reopened: int       #: times it came back
    unexpected: int          #: valid frames that fit no protocol state

    def as_dict(self) -> Dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _mask_ids(mask: int) -> List[int]:
    return [i for i in range(1, MAX_ID + 1) if mask >> i & 1]


# -- nodes --------------------------------------------------------------------

class Node(Closing):
    """What masters and slaves share: one C engine on one serial port.

    Not instantiated directly: use :class:`Master` or :class:`Slave`. A node
    is a context manager (sync and async) that closes it; every method is
    thread-safe. Closing makes every later call raise :class:`ClosedError`.
    """

    _mode: int = -1

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
        self._h: Any = None          # set last: close() and __del__ check it
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._users = 0              # threads inside a C call on self._h
        self._closing = False
        self._closer: Optional[int] = None   # the thread running close()
        self._pump: Optional["AsyncPump"] = None
        self._stash: List[SlaveEvent] = []   # events taken by wait_active, not yet read
        self._tls = threading.local()        # per-thread receive buffers
        if not isinstance(port, (str, bytes, os.PathLike)):
            raise InvalidTypeError(f"port must be a path, not {type(port).__name__}")
        self.path: str = os.fsdecode(port)     #: the serial device
        self.baudrate: int = _int(baudrate, "baudrate", 1, _U32)
        self.id: int = node_id                 #: this node's FAP ID (master 0)
        self.rs485: RS485 = _line_options(rs485)   #: the RS-485 options asked for
        ffi, lib = _native()
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
        out = ffi.new("fapx **")
        code = lib.fapx_open(out, os.fsencode(self.path), opts)
        if code < 0:
            raise _error(code, "open", self.path,
                         ffi.string(lib.fapx_strerror(code)).decode(errors="replace"))
        self._h = out[0]
        log.info("%s open on %s at %d baud (RS-485 %s)", self._label(), self.path,
                 self.baudrate, self.rs485_mode.name)

    # -- lifetime -------------------------------------------------------
    def _label(self) -> str:
        return "master" if self._mode == 0 else f"slave {self.id}"

    def _closed_error(self) -> ClosedError:
        return ClosedError(f"{self._label()} on {self.path} is closed")

    def _call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """fn(handle, *args) with this thread counted in as a user of the handle.

        close() frees the handle only when no thread is inside such a call.
        The bookkeeping is laid out so that an asynchronous exception
        (KeyboardInterrupt from Ctrl-C) cannot leave the count wrong: Python
        runs signal handlers only at function entries, backward jumps and
        after calls, and there is none between ``+= 1`` and ``entered =
        True``, nor between the ``finally`` and ``-= 1``.
        """
        entered = False
        try:
            with self._lock:
                if self._closing:
                    raise self._closed_error()
                self._users += 1
                entered = True
                h = self._h
            return fn(h, *args)
        finally:
            if entered:
                with self._lock:
                    self._users -= 1
                    if self._closing and not self._users:
                        self._idle.notify_all()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called."""
        return self._closing

    def close(self) -> None:
        """Stop the engine and close the port. Idempotent.

        Threads blocked in :meth:`recv` / :meth:`wait_event` raise
        :class:`ClosedError` (within :data:`WAIT_SLICE`); pending asyncio
        waiters get :class:`ClosedError` too.
        """
        lock = getattr(self, "_lock", None)
        if lock is None or getattr(self, "_h", None) is None:
            return
        me = threading.get_ident()
        with lock:
            self._closing = True
            while self._closer is not None and self._h is not None:
                self._idle.wait(WAIT_SLICE)   # another thread is closing it
            if self._h is None:
                return
            self._closer = me
        try:
            pump, self._pump = self._pump, None
            if pump is not None:
                pump.stop()
            with lock:
                while self._users:            # they leave within WAIT_SLICE
                    self._idle.wait(WAIT_SLICE)
                # Forget the handle first: an interrupt before fapx_close leaks
                # it, one after cannot free it twice.
                h, self._h = self._h, None
            self._lib.fapx_close(h)           # joins the engine thread (GIL released)
        finally:
            with lock:
                self._closer = None
                self._idle.notify_all()
        log.info("%s on %s closed", self._label(), self.path)

    async def __aenter__(self) -> "Node":
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def __repr__(self) -> str:
        state = "closed" if self._closing else "open"
        return f"<{type(self).__name__} id={self.id} {self.path} {self.baudrate} baud {state}>"

    # -- information ----------------------------------------------------
    def fileno(self) -> int:
        """The engine's notification fd: readable while a message or event is queued.

        For ``select``/``poll``/``selectors``; never read it. Valid until close.
        """
        return int(self._call(self._lib.fapx_notify_fd))

    @property
    def rs485_mode(self) -> RS485Mode:
        """The RS-485 direction mode actually in force (never AUTO)."""
        lib = self._lib
        return RS485Mode(self._call(lambda h: lib.fap_port_mode(lib.fapx_port(h))))

    def stats(self) -> Stats:
        """A snapshot of the engine's counters."""
        st = self._ffi.new("fapx_stats *")
        self._call(self._lib.fapx_get_stats, st)
        return from_cdata(Stats, st)

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
        dest = self._check_dest(to)
        payload = _payload(data)
        if timeout == 0.0:
            code = self._call(self._lib.fapx_tx, dest, payload, len(payload))
        else:
            deadline = _deadline(timeout)
            while True:
                code = self._call(self._lib.fapx_tx_wait, dest, payload, len(payload),
                                  _slice_ms(deadline))
                if code != -_errno.ETIMEDOUT:
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    code = -_errno.EAGAIN        # still full: QueueFullError
                    break
        if code < 0:
            raise _error(code, "send")
        if log.isEnabledFor(logging.DEBUG):
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
        ffi, lib = self._ffi, self._lib
        try:
            buf, src = self._tls.rx
        except AttributeError:       # first receive in this thread: its own buffers
            buf, src = self._tls.rx = (ffi.new("unsigned char[]", MAX_DATA),
                                       ffi.new("unsigned *"))
        if wait_ms is None:
            n = self._call(lib.fapx_rx, buf, MAX_DATA, src)
        else:
            n = self._call(lib.fapx_rx_wait, buf, MAX_DATA, src, wait_ms)
        if n >= 0:
            msg = Message(int(src[0]), ffi.buffer(buf, n)[:])
            if log.isEnabledFor(logging.DEBUG):   # per message: no label built for nothing
                log.debug("%s: received %d bytes from %d", self._label(), n, msg.source)
            return msg
        if n in (-_errno.EAGAIN, -_errno.ETIMEDOUT):
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
        deadline = _deadline(timeout)
        while True:
            pump = self._pump
            if pump is not None:
                msg = pump.take_rx()
                if msg is not None:
                    return msg
            msg = self._rx_c(_slice_ms(deadline))
            if msg is not None:
                return msg
            if deadline is not None and time.monotonic() >= deadline:
                raise FapTimeoutError(f"recv: no message within {timeout} s")

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
        ev = self._ffi.new("fapx_event *")
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
    def _aio(self) -> "AsyncPump":
        from .fap_aio import AsyncPump

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
            _seconds(timeout, "timeout")
        return await self._aio().get_rx(timeout)

    def __aiter__(self) -> AsyncIterator[Message]:
        """``async for msg in node``: messages until the node is closed."""
        return self._amessages()

    async def _amessages(self) -> AsyncIterator[Message]:
        try:
            while True:
                yield await self.arecv()
        except ClosedError:
            return

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
        import asyncio

        pump = self._pump
        if pump is not None:
            pump.stop()
        await asyncio.get_running_loop().run_in_executor(None, self.close)


class Master(Node):
    """The FAP master (ID 0): polls its listed slaves, runs the ID cycles.

    Args:
        port: serial device path (e.g. ``/dev/ttyUSB0`` or a
            :class:`~fap_py.vbus.VirtualBus` path).
        baudrate: line speed (any termios rate; the vendor API allows
            9600..115200).
        slaves: slave IDs (1..31) to list at once (see :meth:`add_slave`).
        id_cycle: seconds between ID cycles while a listed slave is
            inactive (default 15).
        id_answer_timeout: QUERY_ID -> ID window, seconds (default 1).
        data_done_timeout: SEND_DATA -> DATA_DONE limit, seconds (default 15).
        send_budget: sending time per turn, seconds (default 10).
        byte_gap: inter-byte gap that abandons a partial frame, seconds
            (default: the longer of 4 character times and 10 ms).
        reopen_interval: retry period after the port vanished (default 0.2).
        rx_queue, tx_queue, event_queue: C queue depths (256, 64, 256).
        rs485: :class:`RS485` line options.

    Raises:
        InvalidValueError / InvalidTypeError: bad arguments.
        PortError: the port could not be opened (``errno``, ``path`` set).
    """

    _mode = 0

    def __init__(self, port: PathLike, baudrate: int = 115200, *,
                 slaves: Iterable[int] = (), **options: Any) -> None:
        if isinstance(slaves, (str, bytes)) or not isinstance(slaves, Iterable):
            raise InvalidTypeError("slaves must be an iterable of slave IDs")
        ids = [_slave_id(s) for s in slaves]
        if len(set(ids)) != len(ids):
            raise InvalidValueError(f"slaves lists an ID twice: {ids}")
        super().__init__(port, baudrate, node_id=MASTER_ID, **options)
        try:
            for sid in ids:
                self.add_slave(sid)
        except BaseException:
            self.close()
            raise

    def _check_dest(self, to: Any) -> int:
        return _int(to, "to (a slave ID)", 1, MAX_ID)

    def add_slave(self, id: int) -> None:
        """List slave ``id``; it starts inactive and is queried after the current data cycle.

        Raises:
            SlaveExistsError: already listed.
        """
        sid = _slave_id(id)
        code = self._call(self._lib.fapx_add_slave, sid)
        if code < 0:
            raise _error(code, "add_slave", detail=f"id {sid}")
        log.info("master: slave %d listed", sid)

    def remove_slave(self, id: int) -> None:
        """Stop polling slave ``id``.

        Raises:
            UnknownSlaveError: not listed.
        """
        sid = _slave_id(id)
        code = self._call(self._lib.fapx_remove_slave, sid)
        if code < 0:
            raise _error(code, "remove_slave", detail=f"id {sid}")
        log.info("master: slave %d removed", sid)

    def is_active(self, id: int) -> bool:
        """Whether listed slave ``id`` answers (UnknownSlaveError if not listed)."""
        sid = _slave_id(id)
        code = self._call(self._lib.fapx_slave_active, sid)
        if code < 0:
            raise _error(code, "is_active", detail=f"id {sid}")
        return bool(code)

    @property
    def slaves(self) -> List[int]:
        """The listed slave IDs, ascending."""
        return _mask_ids(self._call(self._lib.fapx_listed_mask))

    @property
    def active_slaves(self) -> List[int]:
        """The listed slaves that answered their last query, ascending."""
        return _mask_ids(self._call(self._lib.fapx_active_mask))

    def wait_active(self, ids: Optional[Iterable[int]] = None,
                    timeout: Optional[float] = None) -> None:
        """Wait until every slave in ``ids`` (default: all listed) is active.

        Waits on engine events; the events it consumes are kept and still
        returned by :meth:`wait_event` / :meth:`events` afterwards.

        Raises:
            FapTimeoutError: not all active within ``timeout`` seconds.
        """
        want = None if ids is None else {_slave_id(i) for i in ids}
        deadline = _deadline(timeout)
        while True:
            target = set(self.slaves) if want is None else want
            if target <= set(self.active_slaves):
                return
            ev = self._ev_c(_slice_ms(deadline))
            if ev is not None:
                with self._lock:
                    self._stash.append(ev)
                    del self._stash[:-self._ev_depth]
            elif deadline is not None and time.monotonic() >= deadline:
                missing = sorted(target - set(self.active_slaves))
                raise FapTimeoutError(f"wait_active: slaves {missing} not active within {timeout} s")


class Slave(Node):
    """A FAP slave (ID 1..31): answers the master's queries, sends in its turn.

    Args:
        port: serial device path.
        baudrate: line speed.
        id: this slave's ID, 1..31.
        Other keyword options as for :class:`Master` (``rs485``, queue
        depths, ``byte_gap``, ``reopen_interval``, ``send_budget``...).
    """

    _mode = 1

    def __init__(self, port: PathLike, baudrate: int = 115200, *, id: int,
                 **options: Any) -> None:
        super().__init__(port, baudrate, node_id=_slave_id(id, "id"), **options)

    def _check_dest(self, to: Any) -> int:
        dest = _int(to, "to (a node ID)", 0, MAX_ID)
        if dest == self.id:
            raise InvalidValueError(f"a slave cannot send to its own ID {dest}")
        return dest

    def send(self, data: Union[bytes, bytearray, memoryview], to: int = MASTER_ID,
             timeout: Optional[float] = 0.0) -> None:
        """Queue ``data`` for node ``to`` (default the master); sent when polled.

        See :meth:`Node.send`.
        """
        super().send(data, to, timeout)
