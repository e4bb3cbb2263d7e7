"""G485 System-Master over the C port layer (device paths) or a pyserial URL/object.

Every transaction is request + reply (none for broadcast) + the seed's
"check operation", which is the Handshake by default (``Check.REREAD`` or
``Check.NONE`` on request), with retries and a per-call timeout. One lock
per port serialises whole transactions (check operation and retries
included), so one master may be shared by many threads.

The transactions themselves are sans-I/O: each is a generator ("flow")
that yields the exchanges it needs, ``(frame, reply prefix or None,
timeout)``, and is sent each reply frame back; :class:`ReplyWaiter` turns
received bytes into that reply or an error. :class:`G485Master` drives the
flows with blocking port calls, :class:`fap_py.g485.aio.AsyncG485Master`
drives the same flows from an asyncio event loop without a thread.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from enum import Enum
from types import GeneratorType
from typing import Any, Callable, Dict, Generator, Iterable, List, Optional, Tuple, Union

from ..errors import PortGoneError
from ..rs485 import RS485
from . import codec
from .codec import (
    EPID,
    HEADER_SIZE,
    HPID,
    REPLY_KINDS,
    WAKE_UP_BAUD_THRESHOLD,
    WAKE_UP_PREAMBLE,
    Data,
    ParseIssue,
    Parser,
    SetCommand,
    is_exact_reply,
)
from .errors import (
    RETRYABLE_ERRORS,
    CheckByteError,
    DeviceErrorWordError,
    G485Error,
    G485FrameError,
    G485ValueError,
    HandshakeMismatchError,
    NoResponseError,
    RereadMismatchError,
    UnexpectedReplyError,
    WriteRefusedError,
)
from .transport import IO, PortIO, PortSpec, open_io

log = logging.getLogger("fap_py.g485")

ID_REGISTER = 7
COMMAND_REGISTER = 6  # write-only: a re-read check ignores it
_HANDSHAKE_PREFIX = codec.reply_prefix(HPID, 3)
_MAX_READ_PLANS = 4096  # cached (address, register, count) read frames per master
#: longest timeout accepted (seconds): anything longer is a mistake, not a wait
MAX_TIMEOUT = 3600.0
MAX_RETRIES = 1000
#: how often a scan probes again after a reply that carries another ID (a late reply)
_SCAN_REPROBES = 3
#: a cached read: request frame, reply prefix, then the address, register and count it is for
_ReadPlan = Tuple[bytes, bytes, int, int, int]
#: one exchange a flow asks for: frame to send, reply prefix awaited (None: no reply), timeout
Step = Tuple[bytes, Optional[bytes], Optional[float]]
Flow = Generator[Step, Optional[bytes], Any]


class Check(Enum):
    """The check operation that closes a transaction."""

    HANDSHAKE = "handshake"  # Handshake-Request/Response, compare MDOC/SDOC or MDIC/SDIC
    REREAD = "reread"        # read the registers (error word) again and compare
    NONE = "none"            # "for less critical applications"


@dataclass
class MasterStats:
    """Counters since the master was opened."""

    transactions: int = 0
    retries: int = 0
    no_response: int = 0
    frame_errors: int = 0
    check_mismatches: int = 0
    ignored_frames: int = 0
    reopens: int = 0


_locks_guard = threading.Lock()
_port_locks: Dict[str, threading.RLock] = {}


def _lock_for(name: str) -> threading.RLock:
    """One lock per port name, shared by every master opened on it in this process."""
    with _locks_guard:
        lock = _port_locks.get(name)
        if lock is None:
            lock = _port_locks[name] = threading.RLock()
        return lock


def _debug() -> bool:
    return log.isEnabledFor(logging.DEBUG)


def _as_check(check: Union[Check, str, None], default: Check) -> Check:
    if check is None:
        return default
    if isinstance(check, Check):
        return check
    try:
        return Check(check)
    except (ValueError, TypeError):
        raise G485ValueError(f"check must be one of {[c.value for c in Check]}, not {check!r}") from None


# -- argument checks: the package's own errors, before any byte is sent ------------

def seconds(value: Any, what: str = "timeout") -> float:
    """A timeout: a finite number of seconds in (0, MAX_TIMEOUT]."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise G485ValueError(f"{what} must be a number of seconds, not {type(value).__name__}")
    if not (0 < value <= MAX_TIMEOUT):  # also false for NaN
        raise G485ValueError(f"{what} must be > 0 and at most {MAX_TIMEOUT:g} seconds, not {value}")
    return float(value)


def whole(value: Any, what: str, lo: int, hi: int) -> int:
    """An int (not a bool) in lo..hi."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise G485ValueError(f"{what} must be an int, not {type(value).__name__}")
    if not lo <= value <= hi:
        raise G485ValueError(f"{what} must be in {lo}..{hi}, not {value}")
    return int(value)


def flag(value: Any, what: str) -> bool:
    """A bool."""
    if not isinstance(value, bool):
        raise G485ValueError(f"{what} must be a bool, not {type(value).__name__}")
    return value


def _timeout_arg(timeout: Optional[float]) -> Optional[float]:
    return None if timeout is None else seconds(timeout)


def _retries_arg(retries: Optional[int]) -> Optional[int]:
    return None if retries is None else whole(retries, "retries", 0, MAX_RETRIES)


# -- sans-I/O: the reply to one request ------------------------------------------------

class ReplyWaiter:
    """Bytes in, the awaited reply frame out (or an error): no I/O, no clock.

    ``feed(chunk)`` returns the whole reply frame, None while more is needed,
    or raises (bad check byte, wrong length byte). At the deadline the
    caller raises :meth:`expired`. ``settle`` (seconds) becomes non-zero once
    a whole reply's worth of unexplained bytes has arrived: the caller then
    allows only that much more idle time.
    """

    __slots__ = ("_m", "_prefix", "_pid", "_length", "size", "_junk", "_problem", "settle")

    def __init__(self, master: "G485Master", prefix: bytes) -> None:
        if not isinstance(master, G485Master):
            raise G485ValueError(f"master must be a G485Master, not {type(master).__name__}")
        if type(prefix) is not bytes or len(prefix) != 5 or not prefix.startswith(codec.START):
            raise G485ValueError(f"prefix must come from codec.reply_prefix(), not {prefix!r}")
        self._m = master
        self._prefix = prefix
        self._length = prefix[3]
        self._pid = prefix[4]
        self.size = HEADER_SIZE + prefix[3]
        self._junk = 0  # bytes received that are neither the reply nor an ignored frame
        self._problem: Optional[str] = None
        self.settle = 0.0

    def wanted(self) -> int:
        """How many bytes to ask the port for next."""
        return self._m._parser.bytes_wanted() or self.size

    def feed(self, chunk: bytes) -> Optional[bytes]:
        """The reply frame if ``chunk`` completes it, else None; raises a G485FrameError."""
        m = self._m
        parser = m._parser
        if not parser.buffered and is_exact_reply(chunk, self._prefix):
            if _debug():
                log.debug("%s rx %s", m.name, chunk.hex(" "))
            return chunk
        size = self.size
        for ev in parser.feed(chunk):
            if isinstance(ev, codec.Packet):
                if ev.kind in REPLY_KINDS and ev.pid == self._pid and len(ev.raw) == size:
                    if _debug():
                        log.debug("%s rx %s", m.name, ev.raw.hex(" "))
                    return ev.raw
                # our own echo, another master, or a late reply to an abandoned request
                m.stats.ignored_frames += 1
                if _debug():
                    log.debug("%s rx ignored %s: %s", m.name, ev.kind.value, ev.raw.hex(" "))
                continue
            if _debug():
                log.debug("%s rx discarded (%s, %s): %s", m.name, ev.issue.name, ev.detail, ev.data.hex(" "))
            if ev.issue is ParseIssue.BAD_CHECK:
                m.stats.frame_errors += 1
                raise CheckByteError(f"{m.name}: reply with bad check byte ({ev.detail}): "
                                     f"{ev.data.hex(' ')}", ev.data)
            self._junk += len(ev.data)
            self._problem = f"{ev.issue.value}: {ev.data.hex(' ')}"
        header = parser.pending_header()
        if header is not None and header[0] == codec.SMA_R and header[1] != self._length:
            m.stats.frame_errors += 1
            raise UnexpectedReplyError(f"{m.name}: reply length byte {header[1]}, expected {self._length}")
        if self._junk + parser.buffered >= size:
            # a whole reply's worth of bytes but no reply: allow only a short idle gap
            self.settle = max(0.01, 30 * m._byte_time)
        return None

    def expired(self, timeout: Optional[float]) -> G485Error:
        """The error to raise when the deadline passed without the reply."""
        m = self._m
        buffered = m._parser.buffered
        if self._junk or buffered:
            m.stats.frame_errors += 1
            return G485FrameError(f"{m.name}: incomplete or garbled reply ({self._junk + buffered} byte(s) "
                                  f"unexplained{'; ' + self._problem if self._problem else ''})")
        return NoResponseError(f"{m.name}: no reply within {timeout or m.timeout:.3f} s")


class G485Master:
    """The System-Master (address 127) on one port.

    :param port: a device path (opened through libfap's port layer, with an
        exclusive lock: a second opener gets :class:`fap_py.port.PortBusyError`),
        libfap's ``tcp://HOST:PORT`` or ``rfc2217://HOST:PORT`` (the same C port
        layer), a pyserial URL (``socket://``, ``loop://``, ``spy://``),
        an open pyserial object, or a raw fd.
    :param baudrate: line speed; above 28,800 baud the wake-up preamble
        ``FF FF FF FF`` precedes the first packet after open (``wake_up``).
    :param timeout: seconds to wait for a reply, on top of the reply's wire time.
    :param retries: extra attempts after a retryable failure (no reply,
        damaged reply, failed check operation).
    :param check: default check operation of every transaction.
    :param wake_up: send the preamble (None: when baudrate > 28800).
    :param wake_after_no_response: send the preamble again before the retry
        that follows a missing reply (the device may have been power-cycled).
    :param set_guard: before a Set (and before a write whose check byte the
        device may already hold), make sure the device's check byte differs
        (the seed's remedy for the handshake's weakness).
    :param set_repeats: how often a Set is sent when ``check`` is REREAD
        (a Set cannot be re-read; the seed recommends sending it 3 times).
    :param factory_address: where a device answers after FACTORY_RESET.
    :param echo: the adapter hears its own transmission (2-wire RS-485 with
        the receiver always on, or a bus with echo): every packet sent is
        read back and compared (the port layer's echo suppression).
    :param rs485: RS-485 line options of a device path (:class:`fap_py.RS485`:
        direction mode, RTS delays, turnaround, exclusive lock).
    """

    def __init__(self, port: PortSpec, baudrate: int = 115200, *, timeout: float = 0.1,
                 retries: int = 2, check: Union[Check, str] = Check.HANDSHAKE,
                 wake_up: Optional[bool] = None, wake_after_no_response: bool = True,
                 set_guard: bool = True, set_repeats: int = 3, factory_address: int = 1,
                 echo: bool = False, rs485: Optional[RS485] = None, **serial_kwargs: Any) -> None:
        self._io: Optional[IO] = None
        self._close_hooks: List[Callable[[], None]] = []   # AsyncG485Master: fail its waiter
        self.timeout = seconds(timeout)
        self.retries = whole(retries, "retries", 0, MAX_RETRIES)
        self.check = _as_check(check, Check.HANDSHAKE)
        if wake_up is not None:
            flag(wake_up, "wake_up")
        self.wake_after_no_response = flag(wake_after_no_response, "wake_after_no_response")
        self.set_guard = flag(set_guard, "set_guard")
        self.set_repeats = whole(set_repeats, "set_repeats", 1, 100)
        self.factory_address = whole(factory_address, "factory_address", codec.MIN_SLAVE_ADDRESS,
                                     codec.MAX_SLAVE_ADDRESS)
        self.echo = flag(echo, "echo")
        self._io = io = open_io(port, baudrate, rs485=rs485, echo=echo, **serial_kwargs)
        self.name = io.name
        self.wake_up = (io.baudrate > WAKE_UP_BAUD_THRESHOLD) if wake_up is None else wake_up
        self._byte_time = 10.0 / io.baudrate
        self._fast_io = io.fast  # one read returns what arrived: the exact-reply fast path applies
        self._wake_pending = self.wake_up
        self._gone = False  # the device vanished: reopen before the next transaction
        self._sent = 0  # bytes of the last write
        self._parser = Parser()
        self._lock = _lock_for(self.name)
        # the check byte each device should hold now (for set_guard)
        self._device_check: Dict[int, int] = {}
        self._non_real_time: set = set()
        self.stats = MasterStats()
        # encoded once: the frames of the hot transactions
        self._read_plans: Dict[Tuple[int, int, int], _ReadPlan] = {}
        self._handshake_requests: Dict[int, bytes] = {}

    # -- context management ----------------------------------------------------

    def close(self) -> None:
        """Close the port. Thread-safe: a transaction in flight in another thread
        (or an :class:`~fap_py.g485.aio.AsyncG485Master` exchange) ends within
        0.5 s with :class:`~fap_py.errors.ClosedError` instead of waiting out its
        timeout and retries. (A pyserial port, which cannot be closed under a
        reader, is closed between transactions.)"""
        io = self._io
        if io is None:
            return
        if isinstance(io, PortIO):
            io.close()      # Port.close: ends the waits in C and the sliced polls
        else:
            with self._lock:
                io.close()
        for hook in list(self._close_hooks):
            hook()

    def __enter__(self) -> "G485Master":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            if self._io is not None and not self._io.closed:
                self._io.close()
        except Exception:  # pragma: no cover - half-built object, interpreter shutdown
            pass

    @property
    def fd(self) -> Optional[int]:
        """The port's file descriptor (None for a pyserial object without one)."""
        return self._io.fd if self._io is not None else None

    # -- the I/O-free parts every driver shares ------------------------------------

    def _wire(self, frame: bytes) -> bytes:
        """The bytes to put on the wire for ``frame`` (with the wake-up preamble when due)."""
        if self._wake_pending:
            self._wake_pending = False
            frame = WAKE_UP_PREAMBLE + frame
            if _debug():
                log.debug("%s tx (wake-up preamble) %s", self.name, frame.hex(" "))
        elif _debug():
            log.debug("%s tx %s", self.name, frame.hex(" "))
        self._parser.clear()
        self._sent = len(frame)
        return frame

    def _reply_wait(self, prefix: bytes, timeout: Optional[float]) -> float:
        """Seconds to wait for the reply: the timeout plus the request's and reply's wire time
        (the request may still be on the wire when the write returns)."""
        return (timeout or self.timeout) + (self._sent + HEADER_SIZE + prefix[3]) * self._byte_time

    def _before(self) -> None:
        """At the start of a transaction: reopen a port whose device vanished."""
        if self._gone:
            self._io.reopen()  # type: ignore[union-attr]  # raises while it is not back
            self._gone = False
            self.stats.reopens += 1
            self._wake_pending = self.wake_up
            log.info("%s reopened", self.name)

    def _after_failure(self, error: BaseException) -> None:
        """After a failed attempt (retried or not): count a missing reply, maybe wake
        the device before the next packet, drop stale input."""
        if isinstance(error, NoResponseError):
            self.stats.no_response += 1
            if self.wake_up and self.wake_after_no_response:
                self._wake_pending = True
        self._io.flush_input()  # type: ignore[union-attr]
        self._parser.clear()

    def _recover(self, error: BaseException) -> None:
        """Between attempts: count the retry (and a failed check), then :meth:`_after_failure`."""
        self.stats.retries += 1
        if isinstance(error, (HandshakeMismatchError, RereadMismatchError)):
            self.stats.check_mismatches += 1
        self._after_failure(error)
        log.info("%s retry after: %s", self.name, error)

    # -- the blocking driver ------------------------------------------------------

    def _exchange_raw(self, frame: bytes, prefix: Optional[bytes], timeout: Optional[float]) -> Optional[bytes]:
        """Discard stale input, send ``frame``, return the whole reply frame starting with
        ``prefix`` (``codec.reply_prefix``; None: no reply awaited)."""
        io = self._io
        if prefix is not None and self._fast_io:
            # one call into C: discard stale input, write, wait for the first chunk
            size = HEADER_SIZE + prefix[3]
            wire = self._wire(frame)
            wait = (timeout or self.timeout) + (self._sent + size) * self._byte_time  # see _reply_wait
            deadline = time.monotonic() + wait
            chunk = io.exchange(wire, size, wait)  # type: ignore[union-attr]
        else:
            io.flush_input()  # type: ignore[union-attr]  # a late reply to an earlier request is not this one's
            io.write(self._wire(frame))  # type: ignore[union-attr]
            if prefix is None:
                return None
            size = HEADER_SIZE + prefix[3]
            wait = (timeout or self.timeout) + (self._sent + size) * self._byte_time  # see _reply_wait
            deadline = time.monotonic() + wait
            chunk = io.read_within(size, wait)  # type: ignore[union-attr]
        if is_exact_reply(chunk, prefix) and not _debug():
            return chunk  # the common case, decided before any waiter object exists
        waiter = ReplyWaiter(self, prefix)
        while True:
            if not chunk:
                raise waiter.expired(timeout)
            raw = waiter.feed(chunk)
            if raw is not None:
                return raw
            if waiter.settle:
                deadline = min(deadline, time.monotonic() + waiter.settle)
            chunk = io.read_some(waiter.wanted(), deadline)  # type: ignore[union-attr]

    def _read_none(self, plan: _ReadPlan, address: int) -> bytes:
        """:meth:`_read_flow` with ``Check.NONE`` and no flow object (the hot path).

        Not a flow: :meth:`_run` calls it directly (``_drive`` passes a value that is
        not a generator straight through)."""
        reply = self._exchange_raw(plan[0], plan[1], None)
        self._device_check[address] = reply[-1]  # type: ignore[index]
        return reply[5:-1]  # type: ignore[index]

    def _drive(self, flow: Any) -> Any:
        """Run one attempt of a transaction: every exchange its flow asks for."""
        if type(flow) is not GeneratorType:
            return flow  # an attempt that did its own exchange (the hot path)
        exchange = self._exchange_raw
        try:
            step = next(flow)
            while True:
                step = flow.send(exchange(*step))
        except StopIteration as done:
            return done.value

    def _run(self, make_flow: Callable[..., Any], retries: Optional[int], *args: Any) -> Any:
        """Run ``make_flow(*args)`` until it succeeds or the retries are used up."""
        lock = self._lock
        lock.acquire()  # explicit acquire/release: cheaper than ``with`` on the hot path
        try:
            if self._io is None or self._io.closed:
                from ..errors import ClosedError
                raise ClosedError(f"{self.name}: master closed")
            self._before()
            self.stats.transactions += 1
            tries = (self.retries if retries is None else retries) + 1
            n = 0
            while True:
                try:
                    return self._drive(make_flow(*args))
                except RETRYABLE_ERRORS as exc:
                    n += 1
                    if n >= tries:
                        self._after_failure(exc)
                        raise
                    self._recover(exc)
                except PortGoneError:
                    self._gone = True
                    raise
        finally:
            lock.release()

    # -- flows: the transactions, without I/O ------------------------------------------

    def _handshake_request(self, address: int) -> bytes:
        request = self._handshake_requests.get(address) if type(address) is int else None
        if request is None:
            request = codec.encode_handshake_request(address)  # validates
            self._handshake_requests[address] = request
        return request

    def _handshake_flow(self, address: int, timeout: Optional[float]) -> Flow:
        reply = yield (self._handshake_request(address), _HANDSHAKE_PREFIX, timeout)
        return reply[5]  # type: ignore[index]

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

    def _read_flow(self, plan: _ReadPlan, address: int, mode: Check, timeout: Optional[float]) -> Flow:
        request, prefix = plan[0], plan[1]
        reply = yield (request, prefix, timeout)
        self._device_check[address] = reply[-1]  # type: ignore[index]
        if mode is Check.HANDSHAKE:
            yield from self._verify_flow(address, reply[-1], "read", timeout)  # type: ignore[index]
        elif mode is Check.REREAD:
            again = yield (request, prefix, timeout)
            self._device_check[address] = again[-1]  # type: ignore[index]
            if again[5:-1] != reply[5:-1]:  # type: ignore[index]
                register, count = prefix[4], prefix[3] - 2
                raise RereadMismatchError(f"{self.name}: device {address} registers {register}.."
                                          f"{register + count - 1} read {reply[5:-1].hex(' ')} "  # type: ignore[index]
                                          f"then {again[5:-1].hex(' ')}")  # type: ignore[index]
        return reply[5:-1]  # type: ignore[index]

    def _guard_flow(self, address: int, mdoc: int, timeout: Optional[float]) -> Flow:
        """Read registers 1, 2, ... until the device's check byte differs from ``mdoc``."""
        register = 1
        while self._device_check.get(address) in (None, mdoc):
            reply = yield (codec.encode_read_request(address, register, 1), codec.reply_prefix(register, 3),
                           timeout)
            self._device_check[address] = reply[-1]  # type: ignore[index]
            if _debug():
                log.debug("%s guard: device %s check byte now 0x%02x (packet's 0x%02x)",
                          self.name, address, reply[-1], mdoc)  # type: ignore[index]
            register += 1

    def _write_flow(self, frame: bytes, address: int, answer_at: int, register: int, payload: bytes,
                    mode: Check, timeout: Optional[float]) -> Flow:
        mdoc = frame[-1]
        last = register + len(payload) - 1
        if mode is Check.HANDSHAKE and self.set_guard and self._device_check.get(address) == mdoc:
            # the device already holds this check byte: a refused write would pass the handshake
            yield from self._guard_flow(address, mdoc, timeout)
        before = self._device_check.get(address)
        yield (frame, None, None)
        self._device_check[answer_at] = mdoc
        if mode is Check.HANDSHAKE:
            try:
                yield from self._verify_flow(answer_at, mdoc, "write", timeout,
                                             before if answer_at == address else None)
            except HandshakeMismatchError as exc:
                self._device_check[answer_at] = exc.got
                raise
        elif mode is Check.REREAD:
            reply = yield (codec.encode_read_request(answer_at, register, len(payload)),
                           codec.reply_prefix(register, len(payload) + 2), timeout)
            self._device_check[answer_at] = reply[-1]  # type: ignore[index]
            got = bytearray(reply[5:-1])  # type: ignore[index]
            want = bytearray(payload)
            if register <= COMMAND_REGISTER <= last:  # write-only: reads back as 0
                got[COMMAND_REGISTER - register] = want[COMMAND_REGISTER - register] = 0
            if got != want:
                raise RereadMismatchError(f"{self.name}: device {answer_at} registers {register}.."
                                          f"{last} hold {bytes(got).hex(' ')} after writing "
                                          f"{bytes(want).hex(' ')}")

    def _error_word_flow(self, request: bytes, address: int, mode: Check, timeout: Optional[float]) -> Flow:
        prefix = codec.reply_prefix(EPID, 4)
        reply = yield (request, prefix, timeout)
        self._device_check[address] = reply[-1]  # type: ignore[index]
        word = (reply[5] << 8) | reply[6]  # type: ignore[index]
        if mode is Check.HANDSHAKE:
            yield from self._verify_flow(address, reply[-1], "error-word read", timeout)  # type: ignore[index]
        elif mode is Check.REREAD:
            again = yield (request, prefix, timeout)
            self._device_check[address] = again[-1]  # type: ignore[index]
            if again[5:7] != reply[5:7]:  # type: ignore[index]
                raise RereadMismatchError(f"{self.name}: device {address} error word read "
                                          f"0x{word:04x} then 0x{(again[5] << 8) | again[6]:04x}")  # type: ignore[index]
        return word

    def _set_flow(self, frame: bytes, address: int, answer_at: int, cmd: SetCommand, mode: Check,
                  use_guard: bool, timeout: Optional[float]) -> Flow:
        mdoc = frame[-1]
        if mode is Check.HANDSHAKE and use_guard:
            yield from self._guard_flow(address, mdoc, timeout)
        yield (frame, None, None)
        self._device_check[answer_at] = mdoc
        if cmd in (SetCommand.RESET, SetCommand.FACTORY_RESET) and self.wake_up:
            self._wake_pending = True  # the device restarts its baud detection
        if mode is Check.HANDSHAKE:
            yield from self._verify_flow(answer_at, mdoc, f"Set {cmd.name}", timeout)
        elif mode is Check.REREAD:
            for _ in range(self.set_repeats - 1):
                yield (frame, None, None)

    def _broadcast_flow(self, frame: bytes) -> Flow:
        yield (frame, None, None)
        # every device that heard it now holds this packet's check byte
        for known in self._device_check:
            self._device_check[known] = frame[-1]

    def _scan_flow(self, address: int, timeout: Optional[float]) -> Flow:
        """Probe ``address`` by reading register 7 (its ID): a reply carrying another ID is a
        late reply to an earlier probe (G485 replies carry no address), so probe again."""
        request = codec.encode_read_request(address, ID_REGISTER, 1)
        prefix = codec.reply_prefix(ID_REGISTER, 3)
        for _ in range(_SCAN_REPROBES):
            reply = yield (request, prefix, timeout)
            self._device_check[address] = reply[-1]  # type: ignore[index]
            if reply[5] == address:  # type: ignore[index]
                return address
            self.stats.ignored_frames += 1
            log.info("%s scan: probe of %d answered with ID %d (a late reply): probing again",
                     self.name, address, reply[5])  # type: ignore[index]
        self._device_check.pop(address, None)
        raise UnexpectedReplyError(f"{self.name}: device {address} kept answering with another ID")

    # -- plans: validate a call, return (flow factory, retries, args, after) ------------

    def _plan_read(self, address: int, register: int, count: int, check: Union[Check, str, None],
                   timeout: Optional[float], retries: Optional[int]) -> Tuple[Any, ...]:
        try:
            plan = self._read_plans.get((address, register, count))
        except TypeError:
            plan = None
        # the same int objects as when cached (True == 1 and 1.0 == 1 must not hit)
        if plan is None or plan[2] is not address or plan[3] is not register or plan[4] is not count:
            plan = self._read_plan(address, register, count)
        mode = self.check if check is None else _as_check(check, self.check)
        if timeout is not None:
            timeout = seconds(timeout)
        if retries is not None:
            retries = _retries_arg(retries)
        return self._read_flow, retries, plan, address, mode, timeout

    def _read_plan(self, address: int, register: int, count: int) -> _ReadPlan:
        """(request frame, reply prefix, address, register, count) of a read, validated by
        the codec; cached for int arguments."""
        plan = (codec.encode_read_request(address, register, count), codec.reply_prefix(register, count + 2),
                address, register, count)
        if type(address) is int and type(register) is int and type(count) is int:
            if len(self._read_plans) >= _MAX_READ_PLANS:
                self._read_plans.clear()
            self._read_plans[(address, register, count)] = plan
        return plan

    def _plan_write(self, address: int, register: int, data: Data, check: Union[Check, str, None],
                    timeout: Optional[float], retries: Optional[int]) -> Tuple[Tuple[Any, ...], Callable[[], None]]:
        frame = codec.encode_write(address, register, data)
        timeout, retries = _timeout_arg(timeout), _retries_arg(retries)
        mode = _as_check(check, self.check)
        if address == codec.BROADCAST:
            return (self._broadcast_flow, 0, frame), lambda: None
        payload = frame[5:-1]
        # after an ID change (real-time mode) the device answers at its new address
        answer_at = address
        last = register + len(payload) - 1
        if register <= ID_REGISTER <= last and address not in self._non_real_time:
            answer_at = payload[ID_REGISTER - register]

        def after() -> None:
            if answer_at != address:
                self._device_check.pop(address, None)

        return (self._write_flow, retries, frame, address, answer_at, register, payload, mode, timeout), after

    def _plan_set(self, address: int, command: Union[SetCommand, int, str], check: Union[Check, str, None],
                  guard: Optional[bool], timeout: Optional[float], retries: Optional[int],
                  factory_address: Optional[int]) -> Tuple[Tuple[Any, ...], Callable[[], None]]:
        cmd = codec.set_command(command)
        frame = codec.encode_set(address, cmd)
        timeout, retries = _timeout_arg(timeout), _retries_arg(retries)
        mode = _as_check(check, self.check)
        use_guard = self.set_guard if guard is None else flag(guard, "guard")
        if address == codec.BROADCAST:
            return (self._broadcast_flow, 0, frame), lambda: self._after_set(address, cmd, address)
        answer_at = address
        if cmd is SetCommand.FACTORY_RESET:
            answer_at = self.factory_address if factory_address is None else whole(
                factory_address, "factory_address", codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS)
        return ((self._set_flow, retries, frame, address, answer_at, cmd, mode, use_guard, timeout),
                lambda: self._after_set(address, cmd, answer_at))

    def _plan_error_word(self, address: int, check: Union[Check, str, None], timeout: Optional[float],
                         retries: Optional[int]) -> Tuple[Any, ...]:
        request = codec.encode_error_word_request(address)
        return (self._error_word_flow, _retries_arg(retries), request, address, _as_check(check, self.check),
                _timeout_arg(timeout))

    def _plan_handshake(self, address: int, timeout: Optional[float], retries: Optional[int]) -> Tuple[Any, ...]:
        self._handshake_request(address)  # validates
        return self._handshake_flow, _retries_arg(retries), address, _timeout_arg(timeout)

    def _scan_addresses(self, addresses: Iterable[int]) -> List[int]:
        try:
            items = list(addresses)
        except TypeError:
            raise G485ValueError(f"addresses must be an iterable of IDs, not {type(addresses).__name__}") from None
        return [whole(a, "scan address", codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS) for a in items]

    # -- transactions ---------------------------------------------------------

    def handshake(self, address: int, *, timeout: Optional[float] = None,
                  retries: Optional[int] = None) -> int:
        """Handshake-Request: the device's SDOC/SDIC (check byte of its last packet)."""
        make, r, *args = self._plan_handshake(address, timeout, retries)
        return self._run(make, r, *args)

    def read(self, address: int, register: int, count: int = 1, *,
             check: Union[Check, str, None] = None, timeout: Optional[float] = None,
             retries: Optional[int] = None) -> bytes:
        """User-Register-Read transaction: ``count`` registers from ``register`` (1..100)."""
        try:
            plan = self._read_plans.get((address, register, count))
        except TypeError:  # unhashable arguments: the codec says what is wrong with them
            plan = None
        if (check is None and timeout is None and retries is None and plan is not None
                and plan[2] is address and plan[3] is register and plan[4] is count):
            if self.check is Check.NONE:  # the hot path: one exchange, no flow to build
                return self._run(self._read_none, None, plan, address)
            return self._run(self._read_flow, None, plan, address, self.check, None)
        make, r, *args = self._plan_read(address, register, count, check, timeout, retries)
        return self._run(make, r, *args)

    def read_register(self, address: int, register: int, **kwargs: Any) -> int:
        """One register as an int."""
        return self.read(address, register, 1, **kwargs)[0]

    def write(self, address: int, register: int, data: Data, *,
              check: Union[Check, str, None] = None, timeout: Optional[float] = None,
              retries: Optional[int] = None) -> None:
        """User-Register-Write transaction (address 0: broadcast, unchecked, no reply).

        A write the device refuses (a read-only register, a bad value) leaves
        its check byte unchanged: the handshake then raises
        :class:`~fap_py.g485.errors.WriteRefusedError`.
        """
        (make, r, *args), after = self._plan_write(address, register, data, check, timeout, retries)
        self._run(make, r, *args)
        after()

    def error_word(self, address: int, *, check: Union[Check, str, None] = None,
                   timeout: Optional[float] = None, retries: Optional[int] = None) -> int:
        """Get-Error-Word transaction: ERRH << 8 | ERRL (see ``codec.ErrorBit``)."""
        make, r, *args = self._plan_error_word(address, check, timeout, retries)
        return self._run(make, r, *args)

    def check_error_word(self, address: int, **kwargs: Any) -> None:
        """Raise DeviceErrorWordError if the device's error word is not zero."""
        word = self.error_word(address, **kwargs)
        if word:
            raise DeviceErrorWordError(address, word)

    def set(self, address: int, command: Union[SetCommand, int, str], *,
            check: Union[Check, str, None] = None, guard: Optional[bool] = None,
            timeout: Optional[float] = None, retries: Optional[int] = None,
            factory_address: Optional[int] = None) -> None:
        """Set transaction (address 0: broadcast, unchecked, no reply).

        After FACTORY_RESET the device answers at its factory ID: the handshake
        goes to ``factory_address`` (default: the master's, 1).

        With the handshake check and ``guard`` on (default ``set_guard``),
        the master first makes sure the device's check byte differs from the
        Set's MDOC by reading registers 1, 2, ... as the seed suggests;
        otherwise a lost Set would pass the handshake.
        """
        (make, r, *args), after = self._plan_set(address, command, check, guard, timeout, retries,
                                                 factory_address)
        self._run(make, r, *args)
        after()

    def scan(self, addresses: Iterable[int] = range(codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS + 1), *,
             timeout: Optional[float] = None, retries: Optional[int] = 0) -> List[int]:
        """The IDs among ``addresses`` that answer, each confirmed by reading its register 7 (ID).

        Input is discarded before every probe, and a reply that carries
        another ID (a late reply to an earlier probe) is not taken as a hit.
        """
        items = self._scan_addresses(addresses)
        timeout, retries = _timeout_arg(timeout), _retries_arg(retries)
        found = []
        for address in items:
            try:
                found.append(self._run(self._scan_flow, retries, address, timeout))
            except (NoResponseError, G485FrameError) as exc:
                log.debug("%s scan: %d absent (%s)", self.name, address, exc)
        return found

    def _after_set(self, address: int, cmd: SetCommand, answer_at: int) -> None:
        targets = list(self._device_check) if address == codec.BROADCAST else [address]
        if cmd is SetCommand.NON_REAL_TIME_WRITE:
            self._non_real_time.update(targets)
        elif cmd in (SetCommand.REAL_TIME_WRITE, SetCommand.RESET, SetCommand.FACTORY_RESET):
            self._non_real_time.difference_update(targets)
        if cmd is SetCommand.FACTORY_RESET and answer_at != address:
            self._device_check.pop(address, None)  # nobody answers there any more

    # -- helpers ----------------------------------------------------------------

    def broadcast_write(self, register: int, data: Data) -> None:
        """User-Register-Write to every device (no reply, no check)."""
        self.write(codec.BROADCAST, register, data)

    def broadcast_set(self, command: Union[SetCommand, int, str], repeats: int = 1) -> None:
        """Set to every device, sent ``repeats`` times (no reply, no check)."""
        for _ in range(whole(repeats, "repeats", 1, 100)):
            self.set(codec.BROADCAST, command)

    def broadcast_read(self, register: int, count: int = 1) -> bytes:
        """Always refused: a broadcast cannot be answered (raises BroadcastReadError)."""
        codec.encode_read_request(codec.BROADCAST, register, count)
        raise AssertionError("unreachable")  # pragma: no cover

    def _sync_items(self, writes: Iterable[Tuple[int, int, Data]]) -> List[Tuple[int, int, Data]]:
        try:
            items: List[Tuple[int, int, Data]] = [tuple(w) for w in writes]  # type: ignore[misc]
        except TypeError:
            raise G485ValueError("writes must be an iterable of (address, register, data)") from None
        for item in items:
            if len(item) != 3:
                raise G485ValueError(f"each write is (address, register, data), not {item!r}")
            address, register, data = item
            if address == codec.BROADCAST:
                raise G485ValueError("sync_write needs individual addresses, not broadcast")
            codec.encode_write(address, register, data)
        return items

    def sync_write(self, writes: Iterable[Tuple[int, int, Data]], *,
                   check: Union[Check, str, None] = None, apply_repeats: int = 1,
                   back_to_real_time: bool = False) -> None:
        """Write several devices, then make them act at the same moment.

        Each device is switched to Non-Real-Time-Write (0x78) and written
        (both checked), then one broadcast Set 0x77 performs every pending
        write at once. The whole sequence holds the port lock.
        """
        items = self._sync_items(writes)
        whole(apply_repeats, "apply_repeats", 1, 100)
        flag(back_to_real_time, "back_to_real_time")
        with self._lock:
            done = set()
            for address, register, data in items:
                if address not in done:
                    self.set(address, SetCommand.NON_REAL_TIME_WRITE, check=check)
                    done.add(address)
                self.write(address, register, data, check=check)
            self.broadcast_set(SetCommand.APPLY_WRITES, repeats=apply_repeats)
            if back_to_real_time:
                for address in done:
                    self.set(address, SetCommand.REAL_TIME_WRITE, check=check)

    def change_id(self, address: int, new_address: int, *, save: bool = False,
                  check: Union[Check, str, None] = None) -> None:
        """Write register 7 (ID); the device answers at ``new_address`` from then on.

        With ``save`` the new ID is stored in EEPROM (Set 0x7C) so it survives a reset.
        """
        whole(address, "address", codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS)
        whole(new_address, "new address", codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS)
        flag(save, "save")
        if address in self._non_real_time:
            raise G485ValueError(f"device {address} is in Non-Real-Time-Write mode; "
                                 f"switch it to real time before changing its ID")
        with self._lock:
            self.write(address, ID_REGISTER, new_address, check=check)
            if save:
                self.set(new_address, SetCommand.SAVE_EEPROM, check=check)

    def send_raw(self, data: bytes) -> None:
        """Put ``data`` on the bus as it is (device tests, fault drills); no reply awaited."""
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise G485ValueError(f"data must be bytes-like, not {type(data).__name__}")
        with self._lock:
            if _debug():
                log.debug("%s tx raw %s", self.name, bytes(data).hex(" "))
            self._io.write(bytes(data))  # type: ignore[union-attr]

    def send_wake_up(self) -> None:
        """Send the wake-up preamble now (e.g. after powering the bus)."""
        with self._lock:
            if _debug():
                log.debug("%s tx wake-up %s", self.name, WAKE_UP_PREAMBLE.hex(" "))
            self._io.write(WAKE_UP_PREAMBLE)  # type: ignore[union-attr]

    # -- test hooks -------------------------------------------------------------

    def believed_check_byte(self, address: int) -> Optional[int]:
        """The check byte the master thinks device ``address`` holds (None: unknown)."""
        whole(address, "address", codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS)
        return self._device_check.get(address)


__all__ = ["Check", "G485Master", "MasterStats", "ReplyWaiter"]
