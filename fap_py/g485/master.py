"""G485 System-Master over any pyserial port (device path, ``loop://``, ``socket://``...).

Every transaction is request + reply (none for broadcast) + the seed's
"check operation", which is the Handshake by default (``Check.REREAD`` or
``Check.NONE`` on request), with retries and a per-call timeout. One lock
per port serialises whole transactions (check operation and retries
included), so one master may be shared by many threads.
"""
from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from enum import Enum
from typing import Any, Dict, Iterable, List, Optional, Tuple, Union

from . import codec
from .codec import (EPID, HEADER_SIZE, HPID, REPLY_KINDS, WAKE_UP_BAUD_THRESHOLD, WAKE_UP_PREAMBLE, Data,
                    Packet, ParseIssue, Parser, SetCommand, is_exact_reply)
from .errors import (RETRYABLE_ERRORS, CheckByteError, DeviceErrorWordError, EchoMismatchError, G485Error,
                     G485FrameError,
                     G485ValueError, HandshakeMismatchError, NoResponseError, RereadMismatchError,
                     UnexpectedReplyError)
from .transport import PortSpec, Transport

log = logging.getLogger("fap_py.g485")

ID_REGISTER = 7
COMMAND_REGISTER = 6  # write-only: a re-read check ignores it
_HANDSHAKE_PREFIX = codec.reply_prefix(HPID, 3)
_MAX_READ_PLANS = 4096  # cached (address, register, count) read frames per master
#: a cached read: request frame, reply prefix, then the address, register and count it is for
_ReadPlan = Tuple[bytes, bytes, int, int, int]


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


_locks_guard = threading.Lock()
_port_locks: Dict[str, threading.RLock] = {}


def _lock_for(name: str) -> threading.RLock:
    """One lock per port name, shared by every master opened on it in this process."""
    with _locks_guard:
        lock = _port_locks.get(name)
        if lock is None:
            lock = _port_locks[name] = threading.RLock()
        return lock


def _as_check(check: Union[Check, str, None], default: Check) -> Check:
    if check is None:
        return default
    try:
        return Check(check) if not isinstance(check, Check) else check
    except ValueError:
        raise G485ValueError(f"check must be one of {[c.value for c in Check]}, not {check!r}") from None


class G485Master:
    """The System-Master (address 127) on one port.

    :param port: a device path or pyserial URL, an open pyserial object, or a raw fd.
    :param baudrate: line speed; above 28,800 baud the wake-up preamble
        ``FF FF FF FF`` precedes the first packet after open (``wake_up``).
    :param timeout: seconds to wait for a reply, on top of the reply's wire time.
    :param retries: extra attempts after a retryable failure (no reply,
        damaged reply, failed check operation).
    :param check: default check operation of every transaction.
    :param wake_up: send the preamble (None: when baudrate > 28800).
    :param wake_after_no_response: send the preamble again before the retry
        that follows a missing reply (the device may have been power-cycled).
    :param set_guard: before a Set, make sure the device's check byte differs
        from the Set's (the seed's remedy for the handshake's weakness).
    :param set_repeats: how often a Set is sent when ``check`` is REREAD
        (a Set cannot be re-read; the seed recommends sending it 3 times).
    :param factory_address: where a device answers after FACTORY_RESET.
    :param echo: the adapter hears its own transmission (2-wire RS-485 with
        the receiver always on, or a bus with echo): every packet sent is
        read back and compared before the reply is awaited.
    """

    def __init__(self, port: PortSpec, baudrate: int = 115200, *, timeout: float = 0.1,
                 retries: int = 2, check: Union[Check, str] = Check.HANDSHAKE,
                 wake_up: Optional[bool] = None, wake_after_no_response: bool = True,
                 set_guard: bool = True, set_repeats: int = 3, factory_address: int = 1,
                 echo: bool = False, **serial_kwargs: Any) -> None:
        if timeout <= 0:
            raise G485ValueError(f"timeout must be positive, got {timeout}")
        if retries < 0:
            raise G485ValueError(f"retries must be >= 0, got {retries}")
        self._io = Transport(port, baudrate=baudrate, **serial_kwargs)
        self.name = self._io.name
        self.timeout = timeout
        self.retries = retries
        self.check = _as_check(check, Check.HANDSHAKE)
        self.wake_up = (self._io.baudrate > WAKE_UP_BAUD_THRESHOLD) if wake_up is None else wake_up
        self.wake_after_no_response = wake_after_no_response
        self.set_guard = set_guard
        self.set_repeats = max(1, set_repeats)
        self.factory_address = factory_address
        self.echo = echo
        self._byte_time = 10.0 / max(1, self._io.baudrate)
        self._fast_io = self._io.fast  # read through the fd: the one-poll fast path applies
        self._wake_pending = self.wake_up
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
        """Close the port (if the master opened it)."""
        with self._lock:
            self._io.close()

    def __enter__(self) -> "G485Master":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- low level: one packet out, one reply in ----------------------------

    def _send(self, frame: bytes) -> None:
        if self._wake_pending:
            self._wake_pending = False
            frame = WAKE_UP_PREAMBLE + frame
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s tx (wake-up preamble) %s", self.name, frame.hex(" "))
        elif log.isEnabledFor(logging.DEBUG):
            log.debug("%s tx %s", self.name, frame.hex(" "))
        self._io.write(frame)
        self._sent = len(frame)
        if self.echo:
            self._read_echo(frame)

    def _read_echo(self, frame: bytes) -> None:
        deadline = time.monotonic() + self.timeout + len(frame) * self._byte_time
        got = b""
        while len(got) < len(frame):
            chunk = self._io.read_some(len(frame) - len(got), deadline)
            if not chunk:
                raise EchoMismatchError(f"{self.name}: echo incomplete ({len(got)} of {len(frame)} bytes): "
                                        "is echo really on?")
            got += chunk
        if got != frame:
            raise EchoMismatchError(f"{self.name}: echo {got.hex(' ')} differs from sent "
                                    f"{frame.hex(' ')} (collision or line fault)")

    def _receive(self, pid: int, length: int, timeout: Optional[float], deadline: float,
                 first: bytes = b"") -> Packet:
        """Wait for the reply with this PID and LENGTH byte; raise what went wrong.

        The general path: any chunking, garbage, echoes and foreign frames.
        ``first`` holds bytes already read by :meth:`_exchange_raw`.
        """
        size = HEADER_SIZE + length
        parser = self._parser
        io = self._io
        junk = 0  # bytes received that are neither the reply nor an ignored frame
        problem: Optional[str] = None
        chunk = first
        while True:
            if not chunk:
                chunk = io.read_some(parser.bytes_wanted() or size, deadline)
            if not chunk:
                if junk or parser.buffered:
                    self.stats.frame_errors += 1
                    raise G485FrameError(f"{self.name}: incomplete or garbled reply "
                                         f"({junk + parser.buffered} byte(s) unexplained"
                                         f"{'; ' + problem if problem else ''})")
                raise NoResponseError(f"{self.name}: no reply within {timeout or self.timeout:.3f} s")
            events = parser.feed(chunk)
            chunk = b""
            for ev in events:
                if isinstance(ev, Packet):
                    if ev.kind in REPLY_KINDS and ev.pid == pid and len(ev.raw) == size:
                        if log.isEnabledFor(logging.DEBUG):
                            log.debug("%s rx %s", self.name, ev.raw.hex(" "))
                        return ev
                    # our own echo, another master, or a late reply to an abandoned request
                    self.stats.ignored_frames += 1
                    if log.isEnabledFor(logging.DEBUG):
                        log.debug("%s rx ignored %s: %s", self.name, ev.kind.value, ev.raw.hex(" "))
                    continue
                if log.isEnabledFor(logging.DEBUG):
                    log.debug("%s rx discarded (%s, %s): %s", self.name, ev.issue.name, ev.detail,
                              ev.data.hex(" "))
                if ev.issue is ParseIssue.BAD_CHECK:
                    self.stats.frame_errors += 1
                    raise CheckByteError(f"{self.name}: reply with bad check byte ({ev.detail}): "
                                         f"{ev.data.hex(' ')}", ev.data)
                junk += len(ev.data)
                problem = f"{ev.issue.value}: {ev.data.hex(' ')}"
            header = parser.pending_header()
            if header is not None and header[0] == codec.SMA_R and header[1] != length:
                self.stats.frame_errors += 1
                raise UnexpectedReplyError(f"{self.name}: reply length byte {header[1]}, "
                                           f"expected {length}")
            if junk + parser.buffered >= size:
                # a whole reply's worth of bytes but no reply: allow only a short idle gap
                deadline = min(deadline, time.monotonic() + max(0.01, 30 * self._byte_time))

    def _exchange_raw(self, frame: bytes, prefix: bytes, timeout: Optional[float]) -> bytes:
        """Send ``frame``, return the whole reply frame that starts with ``prefix`` (``codec.reply_prefix``).

        Fast path (a port read through its fd, no echo, no preamble due, no
        DEBUG logging): write, one poll, one ``os.read`` of the whole reply,
        and :func:`codec.is_exact_reply`. Anything else (a partial or foreign
        chunk, garbage, a timeout) continues in the general :meth:`_receive`
        with the same deadline.
        """
        self._parser.clear()
        io = self._io
        if self._fast_io and not self.echo and not self._wake_pending and not log.isEnabledFor(logging.DEBUG):
            io.write(frame)
            # from here until the reply comes the bus is busy: the bookkeeping costs no latency
            self._sent = len(frame)
            size = HEADER_SIZE + prefix[3]
            # the request may still be on the wire (the OS buffers it), then the reply must cross it
            wait = (timeout or self.timeout) + (self._sent + size) * self._byte_time
            deadline = time.monotonic() + wait
            first = io.read_within(size, wait)
            if is_exact_reply(first, prefix):
                return first
        else:
            self._send(frame)
            deadline = (time.monotonic() + (timeout or self.timeout)
                        + (self._sent + HEADER_SIZE + prefix[3]) * self._byte_time)
            first = b""
        return self._receive(prefix[4], prefix[3], timeout, deadline, first).raw

    def _exchange(self, frame: bytes, pid: int, length: int, timeout: Optional[float]) -> Packet:
        """Send ``frame`` and return its reply (PID ``pid``, LENGTH byte ``length``) decoded."""
        return codec.decode_frame(self._exchange_raw(frame, codec.reply_prefix(pid, length), timeout))

    def _after_failure(self, error: G485Error) -> None:
        """After a failed attempt (retried or not): count a missing reply, maybe wake
        the device before the next packet, drop stale input."""
        if isinstance(error, NoResponseError):
            self.stats.no_response += 1
            if self.wake_up and self.wake_after_no_response:
                self._wake_pending = True
        self._io.flush_input()
        self._parser.clear()

    def _recover(self, error: G485Error) -> None:
        """Between attempts: count the retry (and a failed check), then :meth:`_after_failure`."""
        self.stats.retries += 1
        if isinstance(error, (HandshakeMismatchError, RereadMismatchError)):
            self.stats.check_mismatches += 1
        self._after_failure(error)
        log.info("%s retry after: %s", self.name, error)

    def _run(self, attempt: Any, retries: Optional[int], *args: Any) -> Any:
        """Call ``attempt(*args)`` until it succeeds or the retries are used up."""
        lock = self._lock
        lock.acquire()  # explicit acquire/release: cheaper than ``with`` on the hot path
        try:
            self.stats.transactions += 1
            try:
                return attempt(*args)
            except RETRYABLE_ERRORS as exc:
                error = exc
            return self._retry(error, attempt, retries, args)
        finally:
            lock.release()

    def _retry(self, error: G485Error, attempt: Any, retries: Optional[int], args: Tuple[Any, ...]) -> Any:
        """The attempts after a failed first one (the port lock is held)."""
        tries = (self.retries if retries is None else retries) + 1
        n = 1
        while n < tries:
            self._recover(error)
            n += 1
            try:
                return attempt(*args)
            except RETRYABLE_ERRORS as exc:
                error = exc
        self._after_failure(error)
        raise error

    def _handshake_once(self, address: int, timeout: Optional[float]) -> int:
        request = self._handshake_requests.get(address)
        if request is None:
            request = self._handshake_requests[address] = codec.encode_handshake_request(address)
        return self._exchange_raw(request, _HANDSHAKE_PREFIX, timeout)[5]

    def _verify_handshake(self, address: int, expected: int, what: str, timeout: Optional[float]) -> None:
        got = self._handshake_once(address, timeout)
        if got != expected:
            raise HandshakeMismatchError(
                f"{self.name}: {what} to device {address} failed the handshake: "
                f"master 0x{expected:02x}, device 0x{got:02x}", expected, got)

    # -- transactions ---------------------------------------------------------

    def handshake(self, address: int, *, timeout: Optional[float] = None,
                  retries: Optional[int] = None) -> int:
        """Handshake-Request: the device's SDOC/SDIC (check byte of its last packet)."""
        codec.encode_handshake_request(address)  # validates before locking
        return self._run(lambda: self._handshake_once(address, timeout), retries)

    def read(self, address: int, register: int, count: int = 1, *,
             check: Union[Check, str, None] = None, timeout: Optional[float] = None,
             retries: Optional[int] = None) -> bytes:
        """User-Register-Read transaction: ``count`` registers from ``register`` (1..100)."""
        plan = self._read_plans.get((address, register, count))
        # the same int objects as when cached (True == 1 and 1.0 == 1 must not hit)
        if plan is None or plan[2] is not address or plan[3] is not register or plan[4] is not count:
            plan = self._read_plan(address, register, count)
        mode = self.check if check is None else _as_check(check, self.check)
        return self._run(self._read_once, retries, plan, address, mode, timeout)

    def _read_once(self, plan: _ReadPlan, address: int, mode: Check, timeout: Optional[float]) -> bytes:
        """One attempt of :meth:`read` (a method, not a closure: no cells to build per call)."""
        request, prefix = plan[0], plan[1]
        reply = self._exchange_raw(request, prefix, timeout)
        self._device_check[address] = reply[-1]
        if mode is Check.HANDSHAKE:
            self._verify_handshake(address, reply[-1], "read", timeout)
        elif mode is Check.REREAD:
            again = self._exchange_raw(request, prefix, timeout)
            self._device_check[address] = again[-1]
            if again[5:-1] != reply[5:-1]:
                register, count = prefix[4], prefix[3] - 2
                raise RereadMismatchError(f"{self.name}: device {address} registers {register}.."
                                          f"{register + count - 1} read {reply[5:-1].hex(' ')} "
                                          f"then {again[5:-1].hex(' ')}")
        return reply[5:-1]

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

    def read_register(self, address: int, register: int, **kwargs: Any) -> int:
        """One register as an int."""
        return self.read(address, register, 1, **kwargs)[0]

    def write(self, address: int, register: int, data: Data, *,
              check: Union[Check, str, None] = None, timeout: Optional[float] = None,
              retries: Optional[int] = None) -> None:
        """User-Register-Write transaction (address 0: broadcast, unchecked, no reply)."""
        frame = codec.encode_write(address, register, data)
        payload = frame[5:-1]
        if address == codec.BROADCAST:
            self._broadcast(frame)
            return
        mode = _as_check(check, self.check)
        mdoc = frame[-1]
        # after an ID change (real-time mode) the device answers at its new address
        answer_at = address
        last = register + len(payload) - 1
        if register <= ID_REGISTER <= last and address not in self._non_real_time:
            answer_at = payload[ID_REGISTER - register]

        def attempt() -> None:
            self._parser.clear()
            self._send(frame)
            self._device_check[answer_at] = mdoc
            if mode is Check.HANDSHAKE:
                self._verify_handshake(answer_at, mdoc, "write", timeout)
            elif mode is Check.REREAD:
                request = codec.encode_read_request(answer_at, register, len(payload))
                reply = self._exchange(request, register, len(payload) + 2, timeout)
                self._device_check[answer_at] = reply.check
                got = bytearray(reply.data)
                want = bytearray(payload)
                if register <= COMMAND_REGISTER <= last:  # write-only: reads back as 0
                    got[COMMAND_REGISTER - register] = want[COMMAND_REGISTER - register] = 0
                if got != want:
                    raise RereadMismatchError(f"{self.name}: device {answer_at} registers {register}.."
                                              f"{last} hold {bytes(got).hex(' ')} after writing "
                                              f"{bytes(want).hex(' ')}")

        self._run(attempt, retries)
        if answer_at != address:
            self._device_check.pop(address, None)

    def error_word(self, address: int, *, check: Union[Check, str, None] = None,
                   timeout: Optional[float] = None, retries: Optional[int] = None) -> int:
        """Get-Error-Word transaction: ERRH << 8 | ERRL (see ``codec.ErrorBit``)."""
        request = codec.encode_error_word_request(address)
        mode = _as_check(check, self.check)

        def attempt() -> int:
            reply = self._exchange(request, EPID, 4, timeout)
            self._device_check[address] = reply.check
            if mode is Check.HANDSHAKE:
                self._verify_handshake(address, reply.check, "error-word read", timeout)
            elif mode is Check.REREAD:
                again = self._exchange(request, EPID, 4, timeout)
                self._device_check[address] = again.check
                if again.data != reply.data:
                    raise RereadMismatchError(f"{self.name}: device {address} error word read "
                                              f"0x{reply.error_word:04x} then 0x{again.error_word:04x}")
            return reply.error_word

        return self._run(attempt, retries)

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
        cmd = codec.set_command(command)
        frame = codec.encode_set(address, cmd)
        if address == codec.BROADCAST:
            self._broadcast(frame)
            self._after_set(address, cmd, address)
            return
        mode = _as_check(check, self.check)
        mdoc = frame[-1]
        use_guard = self.set_guard if guard is None else guard
        answer_at = address
        if cmd is SetCommand.FACTORY_RESET:
            answer_at = self.factory_address if factory_address is None else factory_address

        def attempt() -> None:
            if mode is Check.HANDSHAKE and use_guard:
                self._guard_check_byte(address, mdoc, timeout)
            self._parser.clear()
            self._send(frame)
            self._device_check[answer_at] = mdoc
            if cmd in (SetCommand.RESET, SetCommand.FACTORY_RESET) and self.wake_up:
                self._wake_pending = True  # the device restarts its baud detection
            if mode is Check.HANDSHAKE:
                self._verify_handshake(answer_at, mdoc, f"Set {cmd.name}", timeout)
            elif mode is Check.REREAD:
                for _ in range(self.set_repeats - 1):
                    self._send(frame)

        self._run(attempt, retries)
        self._after_set(address, cmd, answer_at)

    def _guard_check_byte(self, address: int, mdoc: int, timeout: Optional[float]) -> None:
        register = 1
        while self._device_check.get(address) in (None, mdoc):
            request = codec.encode_read_request(address, register, 1)
            reply = self._exchange(request, register, 3, timeout)
            self._device_check[address] = reply.check
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s set guard: device %s check byte now 0x%02x (Set MDOC 0x%02x)",
                          self.name, address, reply.check, mdoc)
            register += 1

    def _after_set(self, address: int, cmd: SetCommand, answer_at: int) -> None:
        targets = list(self._device_check) if address == codec.BROADCAST else [address]
        if cmd is SetCommand.NON_REAL_TIME_WRITE:
            self._non_real_time.update(targets)
        elif cmd in (SetCommand.REAL_TIME_WRITE, SetCommand.RESET, SetCommand.FACTORY_RESET):
            self._non_real_time.difference_update(targets)
        if cmd is SetCommand.FACTORY_RESET and answer_at != address:
            self._device_check.pop(address, None)  # nobody answers there any more

    def _broadcast(self, frame: bytes) -> None:
        with self._lock:
            self.stats.transactions += 1
            self._send(frame)
            # every device that heard it now holds this packet's check byte
            for known in self._device_check:
                self._device_check[known] = frame[-1]

    # -- helpers ----------------------------------------------------------------

    def broadcast_write(self, register: int, data: Data) -> None:
        """User-Register-Write to every device (no reply, no check)."""
        self.write(codec.BROADCAST, register, data)

    def broadcast_set(self, command: Union[SetCommand, int, str], repeats: int = 1) -> None:
        """Set to every device, sent ``repeats`` times (no reply, no check)."""
        for _ in range(max(1, repeats)):
            self.set(codec.BROADCAST, command)

    def broadcast_read(self, register: int, count: int = 1) -> bytes:
        """Always refused: a broadcast cannot be answered (raises BroadcastReadError)."""
        codec.encode_read_request(codec.BROADCAST, register, count)
        raise AssertionError("unreachable")  # pragma: no cover

    def sync_write(self, writes: Iterable[Tuple[int, int, Data]], *,
                   check: Union[Check, str, None] = None, apply_repeats: int = 1,
                   back_to_real_time: bool = False) -> None:
        """Write several devices, then make them act at the same moment.

        Each device is switched to Non-Real-Time-Write (0x78) and written
        (both checked), then one broadcast Set 0x77 performs every pending
        write at once. The whole sequence holds the port lock.
        """
        items: List[Tuple[int, int, Data]] = list(writes)
        for address, register, data in items:
            if address == codec.BROADCAST:
                raise G485ValueError("sync_write needs individual addresses, not broadcast")
            codec.encode_write(address, register, data)
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
        if not codec.MIN_SLAVE_ADDRESS <= new_address <= codec.MAX_SLAVE_ADDRESS:
            raise G485ValueError(f"new address {new_address} outside 1..126")
        if address in self._non_real_time:
            raise G485ValueError(f"device {address} is in Non-Real-Time-Write mode; "
                                 f"switch it to real time before changing its ID")
        with self._lock:
            self.write(address, ID_REGISTER, new_address, check=check)
            if save:
                self.set(new_address, SetCommand.SAVE_EEPROM, check=check)

    def send_raw(self, data: bytes) -> None:
        """Put ``data`` on the bus as it is (device tests, fault drills); no reply awaited."""
        with self._lock:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s tx raw %s", self.name, bytes(data).hex(" "))
            self._io.write(bytes(data))

    def send_wake_up(self) -> None:
        """Send the wake-up preamble now (e.g. after powering the bus)."""
        with self._lock:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s tx wake-up %s", self.name, WAKE_UP_PREAMBLE.hex(" "))
            self._io.write(WAKE_UP_PREAMBLE)

    # -- test hooks -------------------------------------------------------------

    def believed_check_byte(self, address: int) -> Optional[int]:
        """The check byte the master thinks device ``address`` holds (None: unknown)."""
        return self._device_check.get(address)


__all__ = ["Check", "G485Master", "MasterStats"]
