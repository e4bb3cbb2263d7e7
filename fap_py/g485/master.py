"""G485 System-Master: the blocking driver of :mod:`fap_py.g485.transaction`.

Every transaction is request + reply (none for broadcast) + the seed's
"check operation", which is the Handshake by default (``Check.REREAD`` or
``Check.NONE`` on request), with retries and a per-call timeout. The
transactions themselves are sans-I/O (:class:`~fap_py.g485.transaction.Session`
makes them, :class:`~fap_py.g485.transaction.Transaction` runs their
retries and reply matching); this module only performs what they ask, with
blocking port calls. One lock per master serialises whole transactions
(check operation and retries included), so one master may be shared by many
threads; a second master on the same device path is refused by the port
layer's exclusive lock.
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable, Iterable, Iterator, List, Optional, Tuple, Union

from .._closing import Closing
from .._validate import MAX_TIMEOUT  # noqa: F401  (kept importable: now the package's ~24 days, was 3,600 s)
from ..errors import ClosedError, PortGoneError
from ..rs485 import RS485
from . import codec
from .codec import WAKE_UP_PREAMBLE, Data, SetCommand
from .errors import DeviceErrorWordError, G485FrameError, G485ValueError, NoResponseError
from .transaction import (  # noqa: F401  (COMMAND_REGISTER, ID_REGISTER, Flow, Step: kept importable)
    COMMAND_REGISTER,
    ID_REGISTER,
    MAX_RETRIES,
    Check,
    Done,
    Fail,
    Flow,
    MasterStats,
    Send,
    Session,
    Step,
    Transaction,
    Wait,
    _ReplyWaiter,
    as_check,
    flag_arg,
    timeout_arg,
    whole_arg,
)
from .transport import IO, PortIO, PortSpec, open_io

log = logging.getLogger("fap_py.g485")

def seconds(value: Any, what: str = "timeout") -> float:
    """Deprecated alias of :func:`fap_py.g485.transaction.timeout_arg`."""
    return timeout_arg(value, what)


def whole(value: Any, what: str, lo: int, hi: int) -> int:
    """Deprecated alias of :func:`fap_py.g485.transaction.whole_arg`."""
    return whole_arg(value, what, lo, hi)


def flag(value: Any, what: str) -> bool:
    """Deprecated alias of :func:`fap_py.g485.transaction.flag_arg`."""
    return flag_arg(value, what)


class ReplyWaiter(_ReplyWaiter):
    """Bytes in, the awaited reply frame out (or an error), for ``master``'s session: what a
    :class:`~fap_py.g485.transaction.Transaction` uses inside (kept for callers of the old API)."""

    __slots__ = ()

    def __init__(self, master: "G485Master", prefix: bytes) -> None:
        if not isinstance(master, G485Master):
            raise G485ValueError(f"master must be a G485Master, not {type(master).__name__}")
        super().__init__(master.session, prefix)


def _option(name: str, check: Callable[[Any], Any], doc: str) -> Any:
    """A master attribute kept by its session, checked when set."""
    def get(self: "G485Master") -> Any:
        return getattr(self.session, name)

    def put(self: "G485Master", value: Any) -> None:
        setattr(self.session, name, check(value))

    return property(get, put, doc=doc)


class G485Master(Closing):
    """The System-Master (address 127) on one port.

    :param port: a device path (opened through libfap's port layer, with an
        exclusive lock: a second opener gets :class:`fap_py.port.PortBusyError`),
        a daemon's ``fapd://`` URL (``fap serve --protocol g485``: a
        ``DaemonG485Master`` with the same calls is returned),
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

    def __new__(cls, port: Any = None, *args: Any, **kwargs: Any) -> Any:
        from ..serve._url import is_daemon_url

        if cls is G485Master and is_daemon_url(port):   # fapd://: a bus fap serve owns
            from .daemon import DaemonG485Master
            return DaemonG485Master(port, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, port: PortSpec, baudrate: int = 115200, *, timeout: float = 0.1,
                 retries: int = 2, check: Union[Check, str] = Check.HANDSHAKE,
                 wake_up: Optional[bool] = None, wake_after_no_response: bool = True,
                 set_guard: bool = True, set_repeats: int = 3, factory_address: int = 1,
                 echo: bool = False, rs485: Optional[RS485] = None, **serial_kwargs: Any) -> None:
        self._io: Optional[IO] = None
        self._close_hooks: List[Callable[[], None]] = []
        #: the sans-I/O state and transactions of this master (shared with an AsyncG485Master)
        self.session = Session(timeout=timeout, retries=retries, check=check, wake_up=wake_up,
                               wake_after_no_response=wake_after_no_response, set_guard=set_guard,
                               set_repeats=set_repeats, factory_address=factory_address, echo=echo)
        self._io = io = open_io(port, baudrate, rs485=rs485, echo=echo, **serial_kwargs)
        self.name = io.name
        self.session.attach(io.name, io.baudrate)
        # one lock per master: a second master on the same device path is refused by the
        # port layer's exclusive lock (RS485(exclusive=False) shares the port on purpose)
        self._lock = threading.RLock()

    timeout = _option("timeout", timeout_arg, "Seconds to wait for a reply, on top of its wire time.")
    retries = _option("retries", lambda v: whole_arg(v, "retries", 0, MAX_RETRIES),
                      "Extra attempts after a retryable failure.")
    check = _option("check", lambda v: as_check(v, Check.HANDSHAKE), "The default check operation.")
    wake_up = _option("wake_up", lambda v: flag_arg(v, "wake_up"), "Send the wake-up preamble when due.")
    wake_after_no_response = _option("wake_after_no_response", lambda v: flag_arg(v, "wake_after_no_response"),
                                     "Wake the device before the retry that follows a missing reply.")
    set_guard = _option("set_guard", lambda v: flag_arg(v, "set_guard"),
                        "Move the device's check byte before a Set or write it may already hold.")
    set_repeats = _option("set_repeats", lambda v: whole_arg(v, "set_repeats", 1, 100),
                          "How often a Set is sent with the re-read check.")
    factory_address = _option("factory_address", lambda v: whole_arg(v, "factory_address", codec.MIN_SLAVE_ADDRESS,
                                                                      codec.MAX_SLAVE_ADDRESS),
                              "Where a device answers after FACTORY_RESET.")
    echo = _option("echo", lambda v: flag_arg(v, "echo"), "The adapter hears its own transmission.")

    @property
    def stats(self) -> MasterStats:
        """Counters since the master was opened: a frozen snapshot."""
        return self.session.stats

    @property
    def io(self) -> IO:
        """The transport (:class:`~fap_py.g485.transport.PortIO` or ``SerialIO``)."""
        io = self._io
        if io is None:  # pragma: no cover - only during a failed __init__
            raise ClosedError("g485: master not open")
        return io

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

    def on_close(self, hook: Callable[[], None]) -> None:
        """Call ``hook()`` when :meth:`close` runs (from any thread): the asyncio driver
        ends its exchange in flight with it."""
        if not callable(hook):
            raise G485ValueError(f"hook must be callable, not {type(hook).__name__}")
        self._close_hooks.append(hook)

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

    def ready_io(self) -> IO:
        """The transport, ready for a transaction: ClosedError once closed, and a port whose
        device vanished is reopened first (raises while it is not back)."""
        io = self._io
        if io is None or io.closed:
            raise ClosedError(f"{self.name}: master closed")
        if self.session.gone:
            io.reopen()
            self.session.reopened()
        return io

    # -- the blocking driver ------------------------------------------------------

    def _run(self, tx: Transaction) -> Any:
        """Perform ``tx`` under the master's lock."""
        lock = self._lock
        lock.acquire()  # explicit acquire/release: cheaper than ``with`` on the hot path
        try:
            return self._drive(self.ready_io(), tx)
        finally:
            lock.release()

    def _run_all(self, txs: Iterator[Transaction]) -> None:
        """Perform a sequence of transactions under one hold of the lock."""
        with self._lock:
            for tx in txs:
                self._run(tx)

    def _drive(self, io: IO, tx: Transaction) -> Any:
        """Do what ``tx`` asks until it is done (blocking port calls)."""
        now = time.monotonic
        fast = io.fast  # one call into C: discard stale input, write, wait for the first chunk
        action: Any = tx.start(now())
        try:
            while True:
                kind = type(action)
                if kind is Send:
                    wire, size, deadline = action
                    if size and fast:
                        assert isinstance(io, PortIO)
                        chunk = io.exchange(wire, size, max(0.0, deadline - now()))
                    else:
                        if fast:
                            assert isinstance(io, PortIO)
                            io.send_fresh(wire)
                        else:  # a late reply to an earlier request is not this one's
                            io.flush_input()
                            io.write(wire)
                        if not size:
                            action = tx.written(now())
                            continue
                        chunk = io.read_within(size, max(0.0, deadline - now()))
                elif kind is Wait:
                    chunk = io.read_some(action.size, action.deadline)
                elif kind is Done:
                    return action.value
                else:
                    assert kind is Fail
                    io.flush_input()
                    raise action.error
                action = tx.receive(chunk, now()) if chunk else tx.expire(now())
        except PortGoneError:
            self.session.port_gone()
            raise

    # -- transactions ---------------------------------------------------------

    def handshake(self, address: int, *, timeout: Optional[float] = None,
                  retries: Optional[int] = None) -> int:
        """Handshake-Request: the device's SDOC/SDIC (check byte of its last packet)."""
        return self._run(self.session.handshake(address, timeout, retries))

    def read(self, address: int, register: int, count: int = 1, *,
             check: Union[Check, str, None] = None, timeout: Optional[float] = None,
             retries: Optional[int] = None) -> bytes:
        """User-Register-Read transaction: ``count`` registers from ``register`` (1..100)."""
        return self._run(self.session.read(address, register, count, check, timeout, retries))

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
        self._run(self.session.write(address, register, data, check, timeout, retries))

    def error_word(self, address: int, *, check: Union[Check, str, None] = None,
                   timeout: Optional[float] = None, retries: Optional[int] = None) -> int:
        """Get-Error-Word transaction: ERRH << 8 | ERRL (see ``codec.ErrorBit``)."""
        return self._run(self.session.error_word(address, check, timeout, retries))

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
        self._run(self.session.set(address, command, check, guard, timeout, retries, factory_address))

    def scan(self, addresses: Iterable[int] = range(codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS + 1), *,
             timeout: Optional[float] = None, retries: Optional[int] = 0) -> List[int]:
        """The IDs among ``addresses`` that answer, each confirmed by reading its register 7 (ID).

        Input is discarded before every probe, and a reply that carries
        another ID (a late reply to an earlier probe) is not taken as a hit.
        """
        s = self.session
        found = []
        for tx_address, tx in [(a, s.probe(a, timeout, retries)) for a in s.scan_addresses(addresses)]:
            try:
                found.append(self._run(tx))
            except (NoResponseError, G485FrameError) as exc:
                log.debug("%s scan: %d absent (%s)", self.name, tx_address, exc)
        return found

    # -- helpers ----------------------------------------------------------------

    def broadcast_write(self, register: int, data: Data) -> None:
        """User-Register-Write to every device (no reply, no check)."""
        self.write(codec.BROADCAST, register, data)

    def broadcast_set(self, command: Union[SetCommand, int, str], repeats: int = 1) -> None:
        """Set to every device, sent ``repeats`` times (no reply, no check)."""
        self._run_all(self.session.broadcast_sets(command, repeats))

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
        write at once. The whole sequence holds the master's lock.
        """
        self._run_all(self.session.sync_write(writes, check, apply_repeats, back_to_real_time))

    def change_id(self, address: int, new_address: int, *, save: bool = False,
                  check: Union[Check, str, None] = None) -> None:
        """Write register 7 (ID); the device answers at ``new_address`` from then on.

        With ``save`` the new ID is stored in EEPROM (Set 0x7C) so it survives a reset.
        """
        self._run_all(self.session.change_id(address, new_address, save, check))

    def send_raw(self, data: bytes) -> None:
        """Put ``data`` on the bus as it is (device tests, fault drills); no reply awaited."""
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise G485ValueError(f"data must be bytes-like, not {type(data).__name__}")
        with self._lock:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s tx raw %s", self.name, bytes(data).hex(" "))
            self.io.write(bytes(data))

    def send_wake_up(self) -> None:
        """Send the wake-up preamble now (e.g. after powering the bus)."""
        with self._lock:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("%s tx wake-up %s", self.name, WAKE_UP_PREAMBLE.hex(" "))
            self.io.write(WAKE_UP_PREAMBLE)

    # -- test hooks -------------------------------------------------------------

    def believed_check_byte(self, address: int) -> Optional[int]:
        """The check byte the master thinks device ``address`` holds (None: unknown)."""
        return self.session.believed_check_byte(address)


__all__ = ["Check", "G485Master", "MasterStats", "ReplyWaiter"]
