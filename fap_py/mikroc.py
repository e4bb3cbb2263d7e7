"""mikroC RS-485 library (master/slave, 0..3 data bytes per frame).

The frame codec and the master/slave logic run in libfap's C core
(``include/mikroc_rs485.h``); this module calls them through cffi.

Frame on the wire::

    0x96 | ADDRESS | DATALEN | DATA1..3 | CRC | 0xA9

Codec (no I/O)::

    frame = encode(0x12, b"\\x01\\x02")              # master -> slave 0x12
    for event in Decoder().feed(frame):              # Message or a FrameError
        ...

Nodes on a serial port (or a :class:`fap_py.vbus.VirtualBus` port)::

    with Master("/dev/ttyUSB0", 19200) as m, ...:
        m.send(0x12, b"\\x01")
        reply = m.receive(timeout=0.5)               # Message(address=0x12, ...)

    with Slave("/dev/ttyUSB1", 19200, address=0x12) as s:
        msg = s.receive(timeout=None)                # blocks until a frame for us
        s.send(b"\\x02")

Rules (docs/mikroc.md): address 50 is broadcast (every slave but those at
150 and 169 takes it); slaves ignore frames for other addresses and frames
sent by other slaves; a damaged frame whose address (and direction) say it
is for this node raises a :class:`MikrocFrameError` subclass from
``receive``; more than 3 data bytes is refused, never truncated.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import Any, List, Optional, Union

from . import _trace  # wire bytes on fap_py.wire.mikroc at DEBUG
from ._daemon_life import DaemonLife
from ._handle import NativeHandle, deadline_of, slice_ms
from ._interruptible import open_interruptibly
from ._native import ffi, lib
from ._stats import Counters, stats_from_c
from ._validate import check_bool, check_bytes, check_int, check_path, check_timeout
from .errors import (
    FapError,
    FapTimeoutError,
    FrameError,
    error_from_code,
)
from .rs485 import RS485, port_options  # the line options every fap_py node takes

__all__ = [
    "NODE_MIN",
    "NODE_MAX",
    "DEFAULT_BAUD",
    "BROADCAST",
    "MAX_DATA",
    "START_BYTE",
    "STOP_BYTE",
    "AbortedFrameError",
    "ChecksumError",
    "DaemonMaster",
    "Decoder",
    "FormatError",
    "LongFrameError",
    "Master",
    "Message",
    "MikrocFrameError",
    "NodeStats",
    "OverrunError",
    "ShortFrameError",
    "Slave",
    "decode",
    "encode",
]

log = logging.getLogger(__name__)

START_BYTE: int = lib.MIKROC_RS485_START_BYTE
STOP_BYTE: int = lib.MIKROC_RS485_STOP_BYTE
BROADCAST: int = lib.MIKROC_RS485_BROADCAST
MAX_DATA: int = lib.MIKROC_RS485_MAX_DATA
# Facts the tools read through fap_py._protocols (never re-typed in a tool).
NODE_MIN: int = lib.MIKROC_RS485_ADDR_MIN       # any address byte a master may send to
NODE_MAX: int = lib.MIKROC_RS485_ADDR_MAX
DEFAULT_BAUD: int = 19200                       # the rate of the vendor's mikroC examples

PathLike = Union[str, "os.PathLike[str]"]


# ---- errors ---------------------------------------------------------------

class MikrocFrameError(FrameError):
    """A mikroC frame failed its checks. ``code`` is the C MIKROC_RS485_E*
    value; ``address`` the address it carried, when that arrived."""

    def __init__(self, code: int, address: Optional[int] = None) -> None:
        text = ffi.string(lib.mikrocRS485_strerror(code)).decode()
        if address is not None:
            text = f"{text} (address {address})"
        super().__init__(text)
        self.code = code
        self.address = address


class ChecksumError(MikrocFrameError):
    """The CRC byte does not match the frame."""


class FormatError(MikrocFrameError):
    """DATALEN bit 5 set, or escape flags that do not fit the bytes."""


class ShortFrameError(MikrocFrameError):
    """The stop byte came before the frame was complete."""


class LongFrameError(MikrocFrameError):
    """No stop byte where DATALEN put it."""


class AbortedFrameError(MikrocFrameError):
    """A new start byte cut the frame off."""


class OverrunError(MikrocFrameError):
    """A frame arrived while the previous one was still unread."""


_ERRORS = {
    lib.MIKROC_RS485_ECRC: ChecksumError,
    lib.MIKROC_RS485_EFORMAT: FormatError,
    lib.MIKROC_RS485_ESHORT: ShortFrameError,
    lib.MIKROC_RS485_ELONG: LongFrameError,
    lib.MIKROC_RS485_EABORT: AbortedFrameError,
    lib.MIKROC_RS485_EOVERRUN: OverrunError,
}


def _frame_error(code: int, address: Optional[int] = None) -> MikrocFrameError:
    return _ERRORS.get(code, MikrocFrameError)(code, address)


# ---- codec ----------------------------------------------------------------

@dataclass(frozen=True)
class Message:
    """A valid frame: the address it carried, its data, and its direction.

    For a master the address is the replying slave's; for a slave it is the
    address the master sent to (its own, or :data:`BROADCAST`)."""

    address: int
    data: bytes
    from_master: bool


def _check_address(address: int) -> int:
    return check_int(address, "address", 0, 255)


def _check_data(data: bytes) -> bytes:
    # bytes(3) would be three zero bytes and bytes("x") a TypeError: accept
    # only byte buffers, so a wrong argument is a clear fap_py error.
    return check_bytes(data, "data of a mikroC frame", 0, MAX_DATA)


def encode(address: int, data: bytes = b"", *, from_master: bool = True) -> bytes:
    """The frame carrying ``data`` (0..3 bytes) to (master) or from (slave)
    ``address``, escaped and checksummed by the C codec."""
    _check_address(address)
    data = _check_data(data)
    check_bool(from_master, "from_master")
    out = ffi.new("uint8_t[]", lib.MIKROC_RS485_FRAME_MAX)
    n = lib.mikrocRS485_Encode(out, data, len(data), address, 1 if from_master else 0)
    if n < 0:
        raise error_from_code(n, "mikroC encode")
    return bytes(ffi.buffer(out, n))


class Decoder:
    """Byte-wise decoder (the C state machine). Bytes outside frames are
    skipped; a 0x96 always starts a new frame."""

    def __init__(self) -> None:
        self._dec = ffi.new("mikrocRS485_decoder *")
        self._frame = ffi.new("mikrocRS485_frame *")
        lib.mikrocRS485_DecoderInit(self._dec)

    def reset(self) -> None:
        """Forget a half-received frame."""
        lib.mikrocRS485_DecoderInit(self._dec)

    def feed(self, data: bytes) -> List[Union[Message, MikrocFrameError]]:
        """Feed received bytes; return the frames and frame errors they
        completed, in order (errors are returned, not raised)."""
        events: List[Union[Message, MikrocFrameError]] = []
        f = self._frame
        for byte in check_bytes(data, "data", 0, 1 << 62):
            r = lib.mikrocRS485_DecoderFeed(self._dec, byte, f)
            if r == lib.MIKROC_RS485_MORE:
                continue
            if r == lib.MIKROC_RS485_FRAME:
                events.append(Message(f.address, bytes(f.data[0:f.count]),
                                      bool(f.datalen & lib.MIKROC_RS485_DL_MASTER)))
            else:
                events.append(_frame_error(r, f.address if f.header else None))
        return events


def decode(frame: bytes) -> Message:
    """Decode exactly one complete frame; raise its error otherwise."""
    frame = check_bytes(frame, "frame", 0, 1 << 62)
    events = Decoder().feed(frame)
    if len(events) == 1 and isinstance(events[0], Message):
        msg = events[0]
        # the decoder skips noise around a frame: exactly one frame means the
        # input is that frame's bytes and nothing else
        if encode(msg.address, msg.data, from_master=msg.from_master) == frame:
            return msg
    for e in events:
        if isinstance(e, MikrocFrameError):
            raise e
    raise FrameError(f"not exactly one mikroC frame: {frame.hex()}")


# ---- nodes on a port ------------------------------------------------------

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


class Master(_Node):
    """A mikroC master on a serial port: ``send`` to a slave, ``receive`` its
    reply. Runs the C master (``mikrocRS485_CtxInitMaster``). ``port_path`` may be a
    daemon's ``fapd://`` URL (``fap serve --protocol mikroc``): a
    :class:`DaemonMaster` is returned."""

    def __new__(cls, port_path: Any = None, *args: Any, **kwargs: Any) -> Any:
        from .serve._url import is_daemon_url

        if cls is Master and is_daemon_url(port_path):
            return DaemonMaster(port_path, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, port_path: PathLike, baudrate: int = DEFAULT_BAUD, *,
                 rs485: Optional[RS485] = None) -> None:
        """Open ``port_path``. ``rs485`` holds the line options (direction
        mode, RTS, echo suppression, turnaround: :class:`fap_py.RS485`,
        the same for every protocol); ``None`` = the port layer's defaults."""
        super().__init__(port_path, baudrate, rs485)

    def _init_ctx(self) -> None:
        lib.mikrocRS485_CtxInitMaster(self._ctx)

    def send(self, address: int, data: bytes = b"") -> None:
        """Send 0..3 bytes to slave ``address`` (50 = broadcast). Input that
        arrived before (a late reply to an earlier request, a half frame) is
        discarded first, so the next ``receive`` returns a reply to this
        (not when a receive() is already running in another thread)."""
        _check_address(address)
        data = _check_data(data)
        # Skipped while another thread already waits in receive(): that
        # thread owns the receive side, and what it gets is its business.
        if self._lock.acquire(blocking=False):
            try:
                r = self._call(lambda _h: lib.mikrocRS485_CtxResetRx(self._ctx))
            finally:
                self._lock.release()
            if r < 0:
                raise error_from_code(r, "flush", self.path)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: tx to %d %s", self.path, address, data.hex())
        self._send(data, address)

    def receive(self, timeout: Optional[float] = 1.0) -> Message:
        """The next frame from a slave: Message(address=slave, data).
        Raises FapTimeoutError, or a MikrocFrameError subclass for a damaged
        frame."""
        return self._receive(timeout, from_master=False)

    async def areceive(self, timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`receive`: the port fd drives it (``loop.add_reader``, no thread)."""
        return await self._areceive(timeout, from_master=False)

    async def arequest(self, address: int, data: bytes = b"",
                       timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`request` (the send itself does not wait for the bus)."""
        self.send(address, data)
        reply = await self.areceive(timeout)
        if reply.address != address:
            raise FrameError(f"reply from slave {reply.address}, expected {address}")
        return reply

    def request(self, address: int, data: bytes = b"", timeout: Optional[float] = 1.0) -> Message:
        """``send`` then ``receive``; the reply must come from ``address``."""
        self.send(address, data)
        reply = self.receive(timeout)
        if reply.address != address:
            raise FrameError(f"reply from slave {reply.address}, expected {address}")
        return reply


#: this module's exceptions by name, as a daemon's answer names them
_WIRE_ERRORS = {c.__name__: (lambda e: _frame_error(int(e.get("code", 0)), e.get("address")))
                for c in [MikrocFrameError, *_ERRORS.values()]}


class DaemonMaster(DaemonLife):
    """A mikroC master on a bus a daemon owns (``fap serve --protocol mikroc``,
    docs/daemon.md): what ``Master("fapd://...")`` returns.

    :meth:`request` is one atomic transaction on the daemon. :meth:`send` to a slave
    queues that transaction at once (reply window: the daemon's ``--timeout``) and
    :meth:`receive` returns its reply (or raises its error); with no request of ours
    outstanding, ``receive`` raises FapTimeoutError at once (the daemon delivers no
    frame nobody asked for). A broadcast (address 50) is sent, no reply awaited.
    ``weight``, ``priority``, ``token`` as for :class:`fap_py.execasync.DaemonMaster`.
    """

    def __init__(self, port_path: PathLike, baudrate: int = DEFAULT_BAUD, *,
                 rs485: Optional[RS485] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None) -> None:
        from .serve._client import Connection, PerLoop

        port_options(baudrate, rs485)            # checked as for a device (the daemon's are used)
        self._conn = Connection(port_path, protocol="mikroc", weight=weight, priority=priority,
                                token=token, name="mikroc master", errors=_WIRE_ERRORS)
        self.path = self._conn.url
        self._outstanding: List[Any] = []
        self._olock = threading.Lock()
        self._hello: dict = {"weight": weight, "priority": priority, "token": token}
        self._aconn = PerLoop(self.path, protocol="mikroc", name="mikroc master",
                              errors=_WIRE_ERRORS, **self._hello)
        self._counts = dict.fromkeys((f.name for f in dataclasses.fields(NodeStats)), 0)

    def send(self, address: int, data: bytes = b"") -> None:
        """Send 0..3 bytes to slave ``address``; a reply is awaited by the daemon for
        :meth:`receive` (none for :data:`BROADCAST`)."""
        _check_address(address)
        data = _check_data(data)
        if address == BROADCAST:
            self._add(self._call("send", address=address, data=data.hex()))
            return
        with self._olock:
            self._outstanding.append(self._conn.submit("request", address=address, data=data.hex()))

    def receive(self, timeout: Optional[float] = 1.0) -> Message:
        """The reply to the oldest :meth:`send` still unanswered."""
        t = check_timeout(timeout)
        with self._olock:
            answer = self._outstanding.pop(0) if self._outstanding else None
        if answer is None:
            raise FapTimeoutError(f"{self.path}: no mikroC frame within {timeout} s "
                                  "(no request of ours outstanding on the daemon)")
        try:
            return self._message(answer.result(timeout=None if t is None else max(t, 0) + 5.0))
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise

    def request(self, address: int, data: bytes = b"", timeout: Optional[float] = 1.0) -> Message:
        """``send`` then ``receive`` as one transaction on the daemon."""
        _check_address(address)
        data = _check_data(data)
        fields: dict = {"address": address, "data": data.hex()}
        t = check_timeout(timeout)
        if t is not None:
            fields["timeout"] = max(t, 1e-6)
        return self._message(self._call("request", **fields))

    async def arequest(self, address: int, data: bytes = b"",
                       timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`request` (an asyncio connection, no thread)."""
        _check_address(address)
        data = _check_data(data)
        fields: dict = {"address": address, "data": data.hex()}
        t = check_timeout(timeout)
        if t is not None:
            fields["timeout"] = max(t, 1e-6)
        conn = await self._aconn.get()
        return self._message(await conn.call("request", **fields))

    def _message(self, answer: dict) -> Message:
        self._add(answer)
        return Message(int(answer["address"]), bytes.fromhex(answer["data"]), False)

    def _add(self, answer: dict) -> None:
        with self._olock:
            for k, v in (answer.get("stats") or {}).items():
                if k in self._counts and isinstance(v, int):
                    self._counts[k] += v

    def _call(self, op: str, **fields: Any) -> dict:
        try:
            return self._conn.call(op, **fields)
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise

    @property
    def stats(self) -> NodeStats:
        """This client's share of the daemon engine's counters."""
        with self._olock:
            return NodeStats(**self._counts)


class Slave(_Node):
    """A mikroC slave at ``address``: ``receive`` frames for it (and
    broadcasts), ``send`` replies. Runs the C slave."""

    _buffer_size = lib.MIKROC_RS485_SLAVE_BUFFER

    def __init__(self, port_path: PathLike, baudrate: int = DEFAULT_BAUD, address: int = 1, *,
                 rs485: Optional[RS485] = None) -> None:
        self.address = _check_address(address)
        super().__init__(port_path, baudrate, rs485)

    def _init_ctx(self) -> None:
        lib.mikrocRS485_CtxInitSlave(self._ctx, self.address)

    def _frame_address(self, raw: bytes) -> int:
        # own or BROADCAST: a slave's 6-byte buffer has no room for it, the C context keeps it
        return int(self._c_stats().last_address)

    def send(self, data: bytes = b"") -> None:
        """Reply with 0..3 bytes (from this slave's address)."""
        data = _check_data(data)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: tx from %d %s", self.path, self.address, data.hex())
        self._send(data, self.address)

    def receive(self, timeout: Optional[float] = 1.0) -> Message:
        """The next frame for this slave: Message(address=own or BROADCAST).
        Raises FapTimeoutError, or a MikrocFrameError subclass for a damaged
        frame addressed to it."""
        return self._receive(timeout, from_master=True)

    async def areceive(self, timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`receive`: the port fd drives it (``loop.add_reader``, no thread)."""
        return await self._areceive(timeout, from_master=True)

    def __repr__(self) -> str:
        return f"Slave({self.path!r}, address={self.address})"
