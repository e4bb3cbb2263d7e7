"""G485 master transactions, sans-I/O: bytes and ``now`` in, frames to send, deadlines and results out.

The shape is h11's ``Connection`` (or ``csrc/execasync/sm_seq.c``): no
file descriptor, no clock, no thread. A :class:`Session` holds what one
master knows between transactions (options, the check byte each device
should hold, the wake-up preamble due, counters) and makes a
:class:`Transaction` per call. A driver runs it::

    action = tx.start(now)
    while True:
        Send(wire, size, deadline) -> discard stale input, write ``wire``; then read up to
                                      ``size`` bytes until ``deadline`` and call
                                      ``tx.receive(chunk, now)`` (``size`` 0: ``tx.written(now)``)
        Wait(size, deadline)       -> read more, then ``tx.receive(chunk, now)``; nothing came
                                      by ``deadline``: ``tx.expire(now)``
        Done(value)                -> the result
        Fail(error)                -> discard stale input, raise ``error`` (retries used up)

The retries, the check operation (handshake, re-read), the set guard and
the reply matching live here, once; :class:`~fap_py.g485.master.G485Master`
(blocking port calls) and :class:`~fap_py.g485.aio.AsyncG485Master` (an
event loop's reader and timer) are the two drivers.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import Enum
from typing import (
    Any,
    Callable,
    Dict,
    Generator,
    Iterable,
    Iterator,
    List,
    NamedTuple,
    Optional,
    Set,
    Tuple,
    Union,
)

from .._validate import check_baud, check_bool, check_int, check_seconds
from . import codec
from .codec import (
    EPID,
    HPID,
    REPLY_KINDS,
    WAKE_UP_BAUD_THRESHOLD,
    WAKE_UP_PREAMBLE,
    Data,
    Packet,
    ParseIssue,
    Parser,
    SetCommand,
    frame_check,
    is_exact_reply,
    prefix_pid,
    reply_packet,
    reply_size,
)
from .errors import (
    RETRYABLE_ERRORS,
    CheckByteError,
    G485Error,
    G485FrameError,
    G485ValueError,
    HandshakeMismatchError,
    NoResponseError,
    RereadMismatchError,
    UnexpectedReplyError,
    WriteRefusedError,
)

log = logging.getLogger("fap_py.g485")

ID_REGISTER = 7
COMMAND_REGISTER = 6  # write-only: a re-read check ignores it
MAX_RETRIES = 1000
_HANDSHAKE_PREFIX = codec.reply_prefix(HPID, 3)
_ERROR_WORD_PREFIX = codec.reply_prefix(EPID, 4)
_MAX_READ_PLANS = 4096  # cached (address, register, count) read frames per session
#: how often a scan probes again after a reply that carries another ID (a late reply)
_SCAN_REPROBES = 3
#: G485's argument errors: a G485ValueError for a wrong type as for a wrong value
_ERR: Dict[str, Any] = {"error": G485ValueError, "type_error": G485ValueError}

#: one exchange a flow asks for: frame to send, reply prefix awaited (None: no reply), timeout
Step = Tuple[bytes, Optional[bytes], Optional[float]]
#: a transaction's logic: yields the exchanges it needs, is sent each reply (None when none awaited)
Flow = Generator[Step, Optional[Packet], Any]


def _debug() -> bool:
    return log.isEnabledFor(logging.DEBUG)


def timeout_arg(value: Any, what: str = "timeout") -> float:
    """A timeout: a finite number of seconds above 0 (at most ``_validate.MAX_TIMEOUT``)."""
    return check_seconds(value, what, lo_open=True, **_ERR)


def whole_arg(value: Any, what: str, lo: int, hi: int) -> int:
    """An int (not a bool) in lo..hi, else a G485ValueError."""
    return check_int(value, what, lo, hi, **_ERR)


def flag_arg(value: Any, what: str) -> bool:
    """A bool, else a G485ValueError."""
    return check_bool(value, what, type_error=G485ValueError)


def _clock(now: Any) -> float:
    """A reading of the driver's monotonic clock: a finite number of seconds."""
    return check_seconds(now, "now", lo=-1e18, hi=1e18, **_ERR)


def _opt_timeout(timeout: Optional[float]) -> Optional[float]:
    return None if timeout is None else timeout_arg(timeout)


def _opt_retries(retries: Optional[int]) -> Optional[int]:
    return None if retries is None else whole_arg(retries, "retries", 0, MAX_RETRIES)


def _address(value: Any, what: str = "address") -> int:
    return whole_arg(value, what, codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS)


class Check(Enum):
    """The check operation that closes a transaction."""

    HANDSHAKE = "handshake"  # Handshake-Request/Response, compare MDOC/SDOC or MDIC/SDIC
    REREAD = "reread"        # read the registers (error word) again and compare
    NONE = "none"            # "for less critical applications"


def as_check(check: Union[Check, str, None], default: Check) -> Check:
    """A :class:`Check` from a member or its value (None: ``default``)."""
    if check is None:
        return default
    if isinstance(check, Check):
        return check
    try:
        return Check(check)
    except (ValueError, TypeError):
        raise G485ValueError(f"check must be one of {[c.value for c in Check]}, not {check!r}") from None


@dataclass(frozen=True)
class MasterStats:
    """Counters since the master was opened (a snapshot: ``master.stats`` makes a new one)."""

    transactions: int = 0
    retries: int = 0
    no_response: int = 0
    frame_errors: int = 0
    check_mismatches: int = 0
    ignored_frames: int = 0
    reopens: int = 0


# -- what a transaction asks its driver to do ------------------------------------------

class Send(NamedTuple):
    """Discard stale input and write ``wire``; then read up to ``size`` bytes of the reply,
    waiting until ``deadline`` (``size`` 0: no reply awaited, call ``written``)."""

    wire: bytes
    size: int
    deadline: float


class Wait(NamedTuple):
    """Read up to ``size`` more bytes, waiting until ``deadline``."""

    size: int
    deadline: float


class Done(NamedTuple):
    """The transaction succeeded with ``value``."""

    value: Any


class Fail(NamedTuple):
    """The transaction failed after its retries: discard stale input and raise ``error``."""

    error: G485Error


Action = Union[Send, Wait, Done, Fail]


# -- the reply to one request ---------------------------------------------------------

class _ReplyWaiter:
    """Bytes in, the awaited reply frame out (or an error): no I/O, no clock.

    ``feed(chunk)`` returns the whole reply frame, None while more is needed,
    or raises (bad check byte, wrong length byte). At the deadline the
    caller raises :meth:`expired`. ``settle`` (seconds) becomes non-zero once
    a whole reply's worth of unexplained bytes has arrived: the caller then
    allows only that much more idle time.
    """

    __slots__ = ("_s", "_prefix", "_pid", "_length", "size", "_junk", "_problem", "settle")

    def __init__(self, session: "Session", prefix: bytes) -> None:
        if not isinstance(session, Session):
            raise G485ValueError(f"session must be a g485 Session, not {type(session).__name__}")
        if type(prefix) is not bytes or len(prefix) != 5 or not prefix.startswith(codec.START):
            raise G485ValueError(f"prefix must come from codec.reply_prefix(), not {prefix!r}")
        self._s = session
        self._prefix = prefix
        self.size = reply_size(prefix)
        self._length = self.size - codec.HEADER_SIZE
        self._pid = prefix_pid(prefix)
        self._junk = 0  # bytes received that are neither the reply nor an ignored frame
        self._problem: Optional[str] = None
        self.settle = 0.0

    def wanted(self) -> int:
        """How many bytes to ask the port for next."""
        return self._s.parser.bytes_wanted() or self.size

    def feed(self, chunk: bytes) -> Optional[bytes]:
        """The reply frame if ``chunk`` completes it, else None; raises a G485FrameError."""
        s = self._s
        parser = s.parser
        if not parser.buffered and is_exact_reply(chunk, self._prefix):
            if _debug():
                log.debug("%s rx %s", s.name, chunk.hex(" "))
            return chunk
        size = self.size
        for ev in parser.feed(chunk):
            if isinstance(ev, codec.Packet):
                if ev.kind in REPLY_KINDS and ev.pid == self._pid and len(ev.raw) == size:
                    if _debug():
                        log.debug("%s rx %s", s.name, ev.raw.hex(" "))
                    return ev.raw
                # our own echo, another master, or a late reply to an abandoned request
                s._count("ignored_frames")
                if _debug():
                    log.debug("%s rx ignored %s: %s", s.name, ev.kind.value, ev.raw.hex(" "))
                continue
            if _debug():
                log.debug("%s rx discarded (%s, %s): %s", s.name, ev.issue.name, ev.detail, ev.data.hex(" "))
            if ev.issue is ParseIssue.BAD_CHECK:
                s._count("frame_errors")
                raise CheckByteError(f"{s.name}: reply with bad check byte ({ev.detail}): "
                                     f"{ev.data.hex(' ')}", ev.data)
            self._junk += len(ev.data)
            self._problem = f"{ev.issue.value}: {ev.data.hex(' ')}"
        header = parser.pending_header()
        if header is not None and header[0] == codec.SMA_R and header[1] != self._length:
            s._count("frame_errors")
            raise UnexpectedReplyError(f"{s.name}: reply length byte {header[1]}, expected {self._length}")
        if self._junk + parser.buffered >= size:
            # a whole reply's worth of bytes but no reply: allow only a short idle gap
            self.settle = max(0.01, 30 * s.byte_time)
        return None

    def expired(self, timeout: Optional[float]) -> G485Error:
        """The error to raise when the deadline passed without the reply."""
        s = self._s
        buffered = s.parser.buffered
        if self._junk or buffered:
            s._count("frame_errors")
            return G485FrameError(f"{s.name}: incomplete or garbled reply ({self._junk + buffered} byte(s) "
                                  f"unexplained{'; ' + self._problem if self._problem else ''})")
        return NoResponseError(f"{s.name}: no reply within {timeout or s.timeout:.3f} s")


# -- one transaction: its flow, the reply matching and the retries ----------------------

class _ReadOnce:
    """The flow of a read without check operation: one exchange. Not a generator, so the
    commonest transaction builds no frame object and raises no StopIteration."""

    __slots__ = ("step", "_address", "_device_check")

    def __init__(self, request: bytes, prefix: bytes, timeout: Optional[float], address: int,
                 device_check: Dict[int, int]) -> None:
        self.step: Step = (request, prefix, timeout)
        self._address = address
        self._device_check = device_check

    def done(self, reply: Packet) -> bytes:
        """The reply came: remember the device's check byte, return the data."""
        self._device_check[self._address] = reply.check
        return reply.data


class Transaction:
    """One master transaction with its retries, driven by events (see the module docstring).

    ``make(*args)`` builds the flow of one attempt; a retryable failure
    (no reply, damaged reply, failed check) starts a new attempt until
    ``retries`` are used up; ``after`` runs once on success.
    """

    __slots__ = ("_s", "_make", "_args", "_tries", "_attempt", "_flow", "_prefix", "_timeout", "_deadline",
                 "_waiter", "_held", "_size", "_after")

    def __init__(self, session: "Session", make: Callable[..., Union[Flow, "_ReadOnce"]], args: Tuple[Any, ...],
                 retries: Optional[int], after: Optional[Callable[[], None]] = None) -> None:
        if not isinstance(session, Session) or not callable(make) or type(args) is not tuple:
            raise G485ValueError("a Transaction is made by a Session (session.read(...), ...)")
        if after is not None and not callable(after):
            raise G485ValueError(f"after must be callable, not {type(after).__name__}")
        retries = _opt_retries(retries)
        self._s = session
        self._make = make
        self._args = args
        self._tries = (session.retries if retries is None else retries) + 1
        self._attempt = 0
        self._flow: Union[Flow, _ReadOnce, None] = None
        self._prefix = b""
        self._timeout: Optional[float] = None
        self._deadline = 0.0
        self._waiter: Optional[_ReplyWaiter] = None
        self._held = b""  # the reply's first bytes while they match it (no waiter yet)
        self._size = 0    # bytes of the awaited reply (reply_size of _prefix)
        self._after = after

    @property
    def deadline(self) -> float:
        """When the reply awaited now is overdue."""
        return self._deadline

    def start(self, now: float) -> Action:
        """The first action (counts the transaction)."""
        if type(now) is not float or now - now:
            now = _clock(now)
        self._s._count("transactions")
        self._flow = self._make(*self._args)
        return self._next(None, now)

    def written(self, now: float) -> Action:
        """A :class:`Send` without a reply (``size`` 0) was written."""
        if type(now) is not float or now - now:
            now = _clock(now)
        return self._next(None, now)

    def receive(self, chunk: bytes, now: float) -> Action:
        """Bytes read from the port since the last action."""
        if type(now) is not float or now - now:
            now = _clock(now)
        waiter = self._waiter
        if waiter is None:
            prefix = self._prefix
            held = self._held + chunk if self._held else chunk
            if is_exact_reply(held, prefix) and not _debug():
                return self._next(reply_packet(held), now)  # the common case: no waiter object
            # a reply arriving in pieces (a paced line): while the bytes so far are the
            # awaited reply's first bytes, wait for the rest without a Parser pass; the
            # Parser would hold them and emit nothing, so feeding them later at once
            # (below) is the same. Anything else goes to the waiter as before.
            if (type(held) is bytes and len(held) < self._size and not self._s.parser.buffered
                    and (prefix.startswith(held) if len(held) <= len(prefix) else held.startswith(prefix))
                    and not _debug()):
                self._held = held
                return Wait(self._size - len(held), self._deadline)
            self._held = b""
            chunk = held
            waiter = self._waiter = _ReplyWaiter(self._s, prefix)
        try:
            raw = waiter.feed(chunk)
        except RETRYABLE_ERRORS as exc:
            return self._failed(exc, now)
        if raw is not None:
            return self._next(reply_packet(raw), now)
        if waiter.settle:
            self._deadline = min(self._deadline, now + waiter.settle)
        return Wait(waiter.wanted(), self._deadline)

    def expire(self, now: float) -> Action:
        """Nothing (more) came: a retry or the failure once ``now`` is past the deadline."""
        if type(now) is not float or now - now:
            now = _clock(now)
        if self._held:  # the reply's first bytes, held without a waiter: hand them over
            held, self._held = self._held, b""
            self._waiter = _ReplyWaiter(self._s, self._prefix)
            try:
                self._waiter.feed(held)  # a clean partial reply: nothing completes or fails
            except RETRYABLE_ERRORS as exc:  # pragma: no cover - held bytes matched the reply
                return self._failed(exc, now)
        if now < self._deadline:
            return Wait(self._waiter.wanted() if self._waiter else self._size, self._deadline)
        waiter = self._waiter or _ReplyWaiter(self._s, self._prefix)
        return self._failed(waiter.expired(self._timeout), now)

    def _next(self, reply: Optional[Packet], now: float) -> Action:
        """Hand ``reply`` to the flow: its next exchange, its result, or a retry."""
        self._waiter = None
        self._held = b""
        flow = self._flow
        if isinstance(flow, _ReadOnce):  # the hot path: no generator, no StopIteration
            if reply is not None:
                self._flow = None
                return Done(flow.done(reply))
            frame, prefix, timeout = flow.step
        elif flow is None:
            raise G485ValueError("transaction not started, or already over")
        else:
            try:
                frame, prefix, timeout = flow.send(reply)
            except StopIteration as done:
                self._flow = None
                if self._after is not None:
                    self._after()
                return Done(done.value)
            except RETRYABLE_ERRORS as exc:
                return self._failed(exc, now)
        s = self._s
        wire = s._wire(frame)
        if prefix is None:
            return Send(wire, 0, now)
        self._prefix = prefix
        self._timeout = timeout
        self._size = size = reply_size(prefix)
        # the timeout plus the request's and the reply's wire time (the request may still be
        # on the wire when the write returns)
        self._deadline = deadline = now + (timeout or s.timeout) + (len(wire) + size) * s.byte_time
        return Send(wire, size, deadline)

    def _failed(self, exc: G485Error, now: float) -> Action:
        s = self._s
        self._attempt += 1
        if self._attempt >= self._tries:
            self._flow = None
            s._after_failure(exc)
            return Fail(exc)
        s._recover(exc)
        self._flow = self._make(*self._args)
        return self._next(None, now)


# -- what one master knows between transactions, and the transactions' flows ----------

class Session:
    """The state of one G485 master between transactions, and the factory of its transactions.

    Options are checked here (``_validate``, G485ValueError); :meth:`attach` gives
    the port's name and baud rate once it is open.
    """

    def __init__(self, *, timeout: float = 0.1, retries: int = 2, check: Union[Check, str] = Check.HANDSHAKE,
                 wake_up: Optional[bool] = None, wake_after_no_response: bool = True, set_guard: bool = True,
                 set_repeats: int = 3, factory_address: int = 1, echo: bool = False) -> None:
        self.timeout = timeout_arg(timeout)
        self.retries = whole_arg(retries, "retries", 0, MAX_RETRIES)
        self.check = as_check(check, Check.HANDSHAKE)
        self._wake_up_arg = None if wake_up is None else flag_arg(wake_up, "wake_up")
        self.wake_after_no_response = flag_arg(wake_after_no_response, "wake_after_no_response")
        self.set_guard = flag_arg(set_guard, "set_guard")
        self.set_repeats = whole_arg(set_repeats, "set_repeats", 1, 100)
        self.factory_address = _address(factory_address, "factory_address")
        self.echo = flag_arg(echo, "echo")
        self.name = "g485"
        self.wake_up = False
        self.byte_time = 10.0 / 115200
        self.wake_pending = False
        self.gone = False  # the device vanished: the driver reopens before the next transaction
        self.parser = Parser()
        #: the check byte each device should hold now (for set_guard)
        self.device_check: Dict[int, int] = {}
        self.non_real_time: Set[int] = set()
        self._counts: Dict[str, int] = dict.fromkeys(MasterStats.__dataclass_fields__, 0)
        # encoded once: the frames of the hot transactions
        self._read_plans: Dict[Tuple[int, int, int], Tuple[bytes, bytes, int, int, int]] = {}
        self._handshake_requests: Dict[int, bytes] = {}

    def attach(self, name: str, baudrate: int) -> None:
        """The port is open: its name (for messages) and line speed (wire times, wake-up)."""
        if not isinstance(name, str):
            raise G485ValueError(f"name must be a str, not {type(name).__name__}")
        baudrate = check_baud(baudrate, **_ERR)
        self.name = name
        self.byte_time = 10.0 / baudrate
        self.wake_up = (baudrate > WAKE_UP_BAUD_THRESHOLD) if self._wake_up_arg is None else self._wake_up_arg
        self.wake_pending = self.wake_up

    @property
    def stats(self) -> MasterStats:
        """The counters now (a frozen snapshot)."""
        return MasterStats(**self._counts)

    def _count(self, what: str) -> None:
        """Add one to counter ``what`` (a :class:`MasterStats` field)."""
        self._counts[what] += 1

    # -- between transactions --------------------------------------------------------

    def _wire(self, frame: bytes) -> bytes:
        """The bytes to put on the wire for ``frame`` (with the wake-up preamble when due)."""
        if self.wake_pending:
            self.wake_pending = False
            frame = WAKE_UP_PREAMBLE + frame
            if _debug():
                log.debug("%s tx (wake-up preamble) %s", self.name, frame.hex(" "))
        elif _debug():
            log.debug("%s tx %s", self.name, frame.hex(" "))
        self.parser.clear()
        return frame

    def port_gone(self) -> None:
        """The device vanished (a driver saw PortGoneError): reopen before the next transaction."""
        self.gone = True

    def reopened(self) -> None:
        """The driver reopened the port."""
        self.gone = False
        self._count("reopens")
        self.wake_pending = self.wake_up
        log.info("%s reopened", self.name)

    def _after_failure(self, error: BaseException) -> None:
        """After a failed attempt (retried or not): count a missing reply, maybe wake the
        device before the next packet, forget buffered bytes."""
        if isinstance(error, NoResponseError):
            self._count("no_response")
            if self.wake_up and self.wake_after_no_response:
                self.wake_pending = True
        self.parser.clear()

    def _recover(self, error: BaseException) -> None:
        """Between attempts: count the retry (and a failed check), then :meth:`after_failure`."""
        self._count("retries")
        if isinstance(error, (HandshakeMismatchError, RereadMismatchError)):
            self._count("check_mismatches")
        self._after_failure(error)
        log.info("%s retry after: %s", self.name, error)

    def believed_check_byte(self, address: int) -> Optional[int]:
        """The check byte the master thinks device ``address`` holds (None: unknown)."""
        return self.device_check.get(_address(address))

    # -- transactions: validate a call, return its Transaction ---------------------------

    def read(self, address: int, register: int, count: int = 1, check: Union[Check, str, None] = None,
             timeout: Optional[float] = None, retries: Optional[int] = None) -> Transaction:
        """User-Register-Read: ``count`` registers from ``register``; result: their bytes."""
        try:
            plan = self._read_plans.get((address, register, count))
        except TypeError:  # unhashable arguments: the codec says what is wrong with them
            plan = None
        # the same int objects as when cached (True == 1 and 1.0 == 1 must not hit)
        if plan is None or plan[2] is not address or plan[3] is not register or plan[4] is not count:
            plan = (codec.encode_read_request(address, register, count), codec.reply_prefix(register, count + 2),
                    address, register, count)
            if type(address) is int and type(register) is int and type(count) is int:
                if len(self._read_plans) >= _MAX_READ_PLANS:
                    self._read_plans.clear()
                self._read_plans[(address, register, count)] = plan
        mode = self.check if check is None else as_check(check, self.check)
        if mode is Check.NONE:
            return Transaction(self, _ReadOnce, (plan[0], plan[1], _opt_timeout(timeout), address,
                                                 self.device_check), retries)
        return Transaction(self, self._read_flow, (plan[0], plan[1], address, mode, _opt_timeout(timeout)),
                           retries)

    def write(self, address: int, register: int, data: Data, check: Union[Check, str, None] = None,
              timeout: Optional[float] = None, retries: Optional[int] = None) -> Transaction:
        """User-Register-Write (address 0: broadcast, unchecked, no reply)."""
        request = codec.decode_frame(codec.encode_write(address, register, data))
        timeout = _opt_timeout(timeout)
        mode = as_check(check, self.check)
        if address == codec.BROADCAST:
            return Transaction(self, self._broadcast_flow, (request.raw,), 0)
        payload = request.data
        # after an ID change (real-time mode) the device answers at its new address
        answer_at = address
        if register <= ID_REGISTER < register + len(payload) and address not in self.non_real_time:
            answer_at = payload[ID_REGISTER - register]

        def after() -> None:
            if answer_at != address:
                self.device_check.pop(address, None)

        return Transaction(self, self._write_flow,
                           (request.raw, address, answer_at, register, payload, mode, timeout), retries, after)

    def set(self, address: int, command: Union[SetCommand, int, str], check: Union[Check, str, None] = None,
            guard: Optional[bool] = None, timeout: Optional[float] = None, retries: Optional[int] = None,
            factory_address: Optional[int] = None) -> Transaction:
        """Set (address 0: broadcast, unchecked, no reply)."""
        cmd = codec.set_command(command)
        frame = codec.encode_set(address, cmd)
        timeout = _opt_timeout(timeout)
        mode = as_check(check, self.check)
        use_guard = self.set_guard if guard is None else flag_arg(guard, "guard")
        if address == codec.BROADCAST:
            return Transaction(self, self._broadcast_flow, (frame,), 0,
                               lambda: self._after_set(address, cmd, address))
        answer_at = address
        if cmd is SetCommand.FACTORY_RESET:
            answer_at = self.factory_address if factory_address is None else _address(
                factory_address, "factory_address")
        return Transaction(self, self._set_flow, (frame, address, answer_at, cmd, mode, use_guard, timeout),
                           retries, lambda: self._after_set(address, cmd, answer_at))

    def error_word(self, address: int, check: Union[Check, str, None] = None, timeout: Optional[float] = None,
                   retries: Optional[int] = None) -> Transaction:
        """Get-Error-Word; result: ERRH << 8 | ERRL."""
        request = codec.encode_error_word_request(address)
        return Transaction(self, self._error_word_flow,
                           (request, address, as_check(check, self.check), _opt_timeout(timeout)),
                           retries)

    def handshake(self, address: int, timeout: Optional[float] = None,
                  retries: Optional[int] = None) -> Transaction:
        """Handshake-Request; result: the device's SDOC/SDIC."""
        self._handshake_request(address)  # validates
        return Transaction(self, self._handshake_flow, (address, _opt_timeout(timeout)), retries)

    def probe(self, address: int, timeout: Optional[float] = None, retries: Optional[int] = 0) -> Transaction:
        """One scan probe: read register 7 (ID); result: ``address`` when the device answers as itself."""
        return Transaction(self, self._scan_flow, (_address(address, "scan address"), _opt_timeout(timeout)),
                           retries)

    def scan_addresses(self, addresses: Iterable[int]) -> List[int]:
        """The IDs to scan, checked."""
        try:
            items = list(addresses)
        except TypeError:
            raise G485ValueError(f"addresses must be an iterable of IDs, not {type(addresses).__name__}") from None
        return [_address(a, "scan address") for a in items]

    # -- sequences of transactions (run under one lock by the driver) ---------------------

    def broadcast_sets(self, command: Union[SetCommand, int, str], repeats: int = 1) -> Iterator[Transaction]:
        """A broadcast Set ``repeats`` times."""
        for _ in range(whole_arg(repeats, "repeats", 1, 100)):
            yield self.set(codec.BROADCAST, command)

    def sync_write(self, writes: Iterable[Tuple[int, int, Data]], check: Union[Check, str, None] = None,
                   apply_repeats: int = 1, back_to_real_time: bool = False) -> Iterator[Transaction]:
        """The transactions of a synchronous write, made one after the other (each after the
        previous one succeeded): Non-Real-Time-Write and the write per device, the broadcast
        Set 0x77, then (``back_to_real_time``) Real-Time-Write per device. Arguments are
        all checked before the first transaction is made."""
        items = self._sync_items(writes)
        whole_arg(apply_repeats, "apply_repeats", 1, 100)
        flag_arg(back_to_real_time, "back_to_real_time")
        return self._sync_sequence(items, check, apply_repeats, back_to_real_time)

    def _sync_sequence(self, items: List[Tuple[int, int, Data]], check: Union[Check, str, None],
                       apply_repeats: int, back_to_real_time: bool) -> Iterator[Transaction]:
        done: List[int] = []
        for address, register, data in items:
            if address not in done:
                yield self.set(address, SetCommand.NON_REAL_TIME_WRITE, check=check)
                done.append(address)
            yield self.write(address, register, data, check=check)
        yield from self.broadcast_sets(SetCommand.APPLY_WRITES, apply_repeats)
        if back_to_real_time:
            for address in done:
                yield self.set(address, SetCommand.REAL_TIME_WRITE, check=check)

    def _sync_items(self, writes: Iterable[Tuple[int, int, Data]]) -> List[Tuple[int, int, Data]]:
        try:
            rows: List[Tuple[Any, ...]] = [tuple(w) for w in writes]
        except TypeError:
            raise G485ValueError("writes must be an iterable of (address, register, data)") from None
        items: List[Tuple[int, int, Data]] = []
        for row in rows:
            if len(row) != 3:
                raise G485ValueError(f"each write is (address, register, data), not {row!r}")
            address, register, data = row
            if address == codec.BROADCAST:
                raise G485ValueError("sync_write needs individual addresses, not broadcast")
            codec.encode_write(address, register, data)
            items.append((address, register, data))
        return items

    def change_id(self, address: int, new_address: int, save: bool = False,
                  check: Union[Check, str, None] = None) -> Iterator[Transaction]:
        """Write register 7 (ID), then (``save``) Set 0x7C at the new address."""
        _address(address)
        _address(new_address, "new address")
        flag_arg(save, "save")
        if address in self.non_real_time:
            raise G485ValueError(f"device {address} is in Non-Real-Time-Write mode; "
                                 f"switch it to real time before changing its ID")
        return self._change_id_sequence(address, new_address, save, check)

    def _change_id_sequence(self, address: int, new_address: int, save: bool,
                            check: Union[Check, str, None]) -> Iterator[Transaction]:
        yield self.write(address, ID_REGISTER, new_address, check=check)
        if save:
            yield self.set(new_address, SetCommand.SAVE_EEPROM, check=check)

    def _after_set(self, address: int, cmd: SetCommand, answer_at: int) -> None:
        targets = list(self.device_check) if address == codec.BROADCAST else [address]
        if cmd is SetCommand.NON_REAL_TIME_WRITE:
            self.non_real_time.update(targets)
        elif cmd in (SetCommand.REAL_TIME_WRITE, SetCommand.RESET, SetCommand.FACTORY_RESET):
            self.non_real_time.difference_update(targets)
        if cmd is SetCommand.FACTORY_RESET and answer_at != address:
            self.device_check.pop(address, None)  # nobody answers there any more

    # -- flows: one attempt of each transaction -------------------------------------------

    def _handshake_request(self, address: int) -> bytes:
        request = self._handshake_requests.get(address) if type(address) is int else None
        if request is None:
            request = codec.encode_handshake_request(address)  # validates
            self._handshake_requests[address] = request
        return request

    def _handshake_flow(self, address: int, timeout: Optional[float]) -> Flow:
        reply = yield (self._handshake_request(address), _HANDSHAKE_PREFIX, timeout)
        assert reply is not None
        return reply.handshake_value

    def _verify_flow(self, address: int, expected: int, what: str, timeout: Optional[float],
                     before: Optional[int] = None) -> Flow:
        """Handshake and compare; ``before``: the check byte the device held before a write."""
        got = yield from self._handshake_flow(address, timeout)
        if got != expected:
            if before is not None and got == before:
                raise WriteRefusedError(
                    f"{self.name}: {what} to device {address} refused or lost: its check byte "
                    f"0x{got:02x} did not change (expected 0x{expected:02x}); a read-only register "
                    f"or a bad value? (see its error word)", expected, got)
            raise HandshakeMismatchError(
                f"{self.name}: {what} to device {address} failed the handshake: "
                f"master 0x{expected:02x}, device 0x{got:02x}", expected, got)

    def _checked_flow(self, request: bytes, prefix: bytes, address: int, mode: Check, what: str,
                      timeout: Optional[float]) -> Flow:
        """One request and its check operation (handshake, or the same request again
        and the same data); returns the reply."""
        reply = yield (request, prefix, timeout)
        assert reply is not None
        self.device_check[address] = reply.check
        if mode is Check.HANDSHAKE:
            yield from self._verify_flow(address, reply.check, what, timeout)
        elif mode is Check.REREAD:
            again = yield (request, prefix, timeout)
            assert again is not None
            self.device_check[address] = again.check
            if again.data != reply.data:
                raise RereadMismatchError(f"{self.name}: device {address} {what}: {reply.data.hex(' ')}, "
                                          f"then {again.data.hex(' ')}")
        return reply

    def _read_flow(self, request: bytes, prefix: bytes, address: int, mode: Check,
                   timeout: Optional[float]) -> Flow:
        reply = yield from self._checked_flow(request, prefix, address, mode, "read", timeout)
        return reply.data

    def _guard_flow(self, address: int, mdoc: int, timeout: Optional[float]) -> Flow:
        """Read registers 1, 2, ... until the device's check byte differs from ``mdoc``."""
        register = 1
        while self.device_check.get(address) in (None, mdoc):
            reply = yield (codec.encode_read_request(address, register, 1), codec.reply_prefix(register, 3),
                           timeout)
            assert reply is not None
            self.device_check[address] = reply.check
            if _debug():
                log.debug("%s guard: device %s check byte now 0x%02x (packet's 0x%02x)",
                          self.name, address, reply.check, mdoc)
            register += 1

    def _write_flow(self, frame: bytes, address: int, answer_at: int, register: int, payload: bytes,
                    mode: Check, timeout: Optional[float]) -> Flow:
        mdoc = frame_check(frame)
        last = register + len(payload) - 1
        if mode is Check.HANDSHAKE and self.set_guard and self.device_check.get(address) == mdoc:
            # the device already holds this check byte: a refused write would pass the handshake
            yield from self._guard_flow(address, mdoc, timeout)
        before = self.device_check.get(address)
        yield (frame, None, None)
        self.device_check[answer_at] = mdoc
        if mode is Check.HANDSHAKE:
            try:
                yield from self._verify_flow(answer_at, mdoc, "write", timeout,
                                             before if answer_at == address else None)
            except HandshakeMismatchError as exc:
                self.device_check[answer_at] = exc.got
                raise
        elif mode is Check.REREAD:
            reply = yield (codec.encode_read_request(answer_at, register, len(payload)),
                           codec.reply_prefix(register, len(payload) + 2), timeout)
            assert reply is not None
            self.device_check[answer_at] = reply.check
            got = bytearray(reply.data)
            want = bytearray(payload)
            if register <= COMMAND_REGISTER <= last:  # write-only: reads back as 0
                got[COMMAND_REGISTER - register] = want[COMMAND_REGISTER - register] = 0
            if got != want:
                raise RereadMismatchError(f"{self.name}: device {answer_at} registers {register}.."
                                          f"{last} hold {bytes(got).hex(' ')} after writing "
                                          f"{bytes(want).hex(' ')}")

    def _error_word_flow(self, request: bytes, address: int, mode: Check, timeout: Optional[float]) -> Flow:
        reply = yield from self._checked_flow(request, _ERROR_WORD_PREFIX, address, mode, "error-word read",
                                              timeout)
        return reply.error_word

    def _set_flow(self, frame: bytes, address: int, answer_at: int, cmd: SetCommand, mode: Check,
                  use_guard: bool, timeout: Optional[float]) -> Flow:
        mdoc = frame_check(frame)
        if mode is Check.HANDSHAKE and use_guard:
            yield from self._guard_flow(address, mdoc, timeout)
        yield (frame, None, None)
        self.device_check[answer_at] = mdoc
        if cmd in (SetCommand.RESET, SetCommand.FACTORY_RESET) and self.wake_up:
            self.wake_pending = True  # the device restarts its baud detection
        if mode is Check.HANDSHAKE:
            yield from self._verify_flow(answer_at, mdoc, f"Set {cmd.name}", timeout)
        elif mode is Check.REREAD:
            for _ in range(self.set_repeats - 1):
                yield (frame, None, None)

    def _broadcast_flow(self, frame: bytes) -> Flow:
        yield (frame, None, None)
        # every device that heard it now holds this packet's check byte
        for known in self.device_check:
            self.device_check[known] = frame_check(frame)

    def _scan_flow(self, address: int, timeout: Optional[float]) -> Flow:
        """Probe ``address`` by reading register 7 (its ID): a reply carrying another ID is a
        late reply to an earlier probe (G485 replies carry no address), so probe again."""
        request = codec.encode_read_request(address, ID_REGISTER, 1)
        prefix = codec.reply_prefix(ID_REGISTER, 3)
        for _ in range(_SCAN_REPROBES):
            reply = yield (request, prefix, timeout)
            assert reply is not None
            self.device_check[address] = reply.check
            if reply.data[0] == address:
                return address
            self._count("ignored_frames")
            log.info("%s scan: probe of %d answered with ID %d (a late reply): probing again",
                     self.name, address, reply.data[0])
        self.device_check.pop(address, None)
        raise UnexpectedReplyError(f"{self.name}: device {address} kept answering with another ID")


__all__ = ["Action", "Check", "Done", "Fail", "Flow", "MasterStats", "Send", "Session", "Step",
           "Transaction", "Wait", "as_check", "flag_arg", "timeout_arg", "whole_arg"]
