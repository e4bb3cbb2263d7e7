"""Exec async protocol (DLE STX ... DLE ETX + CRC-16) over libfap.

Everything here runs in the C core (``include/exec_async.h`` and
``include/exec_async_engine.h``) through the cffi extension:

* :func:`encode` / :class:`Decoder`: ``execAsyncBufferOut`` and
  ``execAsyncByteIn`` (one frame per call / a byte stream).
* :class:`StructLayout`: ``execPackDataEx`` / ``execUnPackDataEx`` from a
  Python description of a C structure (native layout <-> packed big-endian).
* :class:`Master` and :class:`Slave`: the master/slave engine on a libfap
  port (a serial device or a :class:`fap_py.vbus.VirtualBus` port), with
  per-node sequence numbers, retries and the resend-without-processing
  rule. Time values are in seconds.

Example::

    line = RS485(mode=RS485Mode.NONE)
    with VirtualBus(ports=2) as bus, \\
         Slave(bus.paths[1], node=1, handler=lambda req: req.data[::-1], rs485=line) as slave, \\
         Master(bus.paths[0], timeout=0.05, rs485=line) as master:
        slave.start()
        assert master.transact(1, b"abc") == b"cba"
"""
from __future__ import annotations

import asyncio
import ctypes
import dataclasses
import errno
import logging
import os
import threading
import time
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Type, TypeVar, Union

from . import _trace  # wire bytes on fap_py.wire.exec at DEBUG
from ._daemon_life import DaemonLife
from ._handle import NativeHandle, deadline_of
from ._interruptible import open_interruptibly
from ._native import ffi, lib
from ._stats import Counters, stats_from_c
from ._validate import check_bytes, check_int, check_path, check_seconds, timeout_ms
from .errors import (
    ClosedError,
    FapError,
    FapTimeoutError,
    FrameError,
    InvalidTypeError,
    InvalidValueError,
    PortError,
    error_from_code,
)
from .rs485 import DEFAULT_BAUD as _DEFAULT_BAUD
from .rs485 import RS485, RS485Mode, port_options  # the line options every fap_py node takes

log = logging.getLogger("fap_py.execasync")

# Every constant is the C core's (include/exec_async.h), through cffi.
DLE: int = lib.EXEC_ASYNC_DLE
STX: int = lib.EXEC_ASYNC_STX
ETX: int = lib.EXEC_ASYNC_ETX
BROADCAST: int = lib.EXEC_ASYNC_BROADCAST
MAX_DATA: int = lib.EXEC_ASYNC_MAX_DATA          # RawSize is a byte
MAX_FRAME: int = lib.EXEC_ASYNC_MAX_FRAME        # every data byte a DLE
# Facts the tools read through fap_py._protocols (never re-typed in a tool).
NODE_MIN: int = lib.EXEC_ASYNC_NODE_MIN         # node numbers a master addresses
NODE_MAX: int = lib.EXEC_ASYNC_NODE_MAX
DEFAULT_BAUD: int = _DEFAULT_BAUD

BytesLike = Union[bytes, bytearray, memoryview]


# ---- errors -----------------------------------------------------------------

class ExecAsyncError(FapError):
    """Base of the exec async errors."""


class ExecValueError(ExecAsyncError, InvalidValueError):
    """A node number, payload or structure description is out of range."""


class ExecTypeError(ExecValueError, InvalidTypeError):
    """An argument has the wrong type (also an InvalidTypeError / TypeError)."""


class NoReplyError(ExecAsyncError, FapTimeoutError):
    """The node did not answer, after every retry."""


class CorruptReplyError(ExecAsyncError, FrameError):
    """Every attempt failed and the last one got a corrupted frame (CRC, framing)."""


def _raise_for(code: int, what: str, path: Optional[str] = None) -> None:
    if code >= 0:
        return
    if code == -errno.ETIMEDOUT:
        if what in ("open", "reopen"):   # no connection within connect_ms: a port error
            raise PortError(errno.ETIMEDOUT, f"{what}: connection timed out", path)
        raise NoReplyError(f"{what}: no reply")
    if code == -errno.EBADMSG:
        raise CorruptReplyError(f"{what}: corrupted reply")
    if code in (-errno.EINVAL, -errno.EMSGSIZE):
        raise ExecValueError(f"{what}: {ffi.string(lib.fap_port_strerror(code)).decode()}")
    if code == -errno.ECANCELED:
        raise ClosedError(f"{what}: stopped")
    raise error_from_code(code, what, path)


_ERR: Dict[str, Any] = {"error": ExecValueError, "type_error": ExecTypeError}


def _check_node(node: int, *, allow_broadcast: bool = False) -> int:
    return check_int(node, "node", 1, BROADCAST if allow_broadcast else BROADCAST - 1, **_ERR)


def _check_data(data: BytesLike) -> bytes:
    return check_bytes(data, "data", 0, MAX_DATA, **_ERR)


# ---- framing ------------------------------------------------------------------

class Status(IntEnum):
    """What :meth:`Decoder.feed` found (``execAsyncStateDef.Status``)."""

    GOOD = lib.EXEC_ASYNC_GOOD
    BAD_CRC = lib.EXEC_ASYNC_BAD_CRC
    OVERFLOW = lib.EXEC_ASYNC_OVERFLOW
    FRAMING = lib.EXEC_ASYNC_FRAMING


@dataclass(frozen=True)
class Frame:
    """One decoded frame; only ``GOOD`` frames can be trusted."""

    node: int
    seq: int
    data: bytes
    status: Status

    @property
    def ok(self) -> bool:
        return self.status is Status.GOOD


def encode(node: int, data: BytesLike = b"", seq: int = 0) -> bytes:
    """Format one frame (``execAsyncBufferOut``). node and seq are 0..255."""
    check_int(node, "node", 0, 255, **_ERR)
    check_int(seq, "seq", 0, 255, **_ERR)
    raw = _check_data(data)
    out = ffi.new("byte[]", MAX_FRAME)
    n = lib.execAsyncBufferOut(node, ffi.from_buffer("byte[]", raw) if raw else ffi.NULL,
                               out, len(raw), seq)
    return bytes(ffi.buffer(out, n))


class Decoder:
    """Feed received bytes, get frames (``execAsyncByteIn`` one byte at a time).

    ``buffer_size`` (1..255) limits the payload; a longer one is reported
    as ``Status.OVERFLOW`` with its first ``buffer_size`` bytes.

    Thread-safe: :meth:`feed` and :meth:`reset` hold the decoder's lock, so
    calls from several threads are serialised and each call decodes its
    bytes as one run (the C state is never seen half-updated). A decoder is
    one byte stream: bytes fed from two threads are decoded in the order the
    calls take the lock, and frames interleaved that way are reported as
    what they are on the wire (framing or CRC errors), never as an error of
    the decoder.
    """

    def __init__(self, buffer_size: int = MAX_DATA) -> None:
        check_int(buffer_size, "buffer_size", 1, MAX_DATA, **_ERR)
        self._size = buffer_size
        self._lock = threading.Lock()
        self._buf = ffi.new("byte[]", buffer_size)
        self.reset()

    def reset(self) -> None:
        """Forget any partial frame; wait for the next DLE STX."""
        state = ffi.new("struct execAsyncStateDef *")
        state.BufferSize = self._size % 256
        with self._lock:
            self._state = state

    def feed(self, data: BytesLike) -> List[Frame]:
        """The frames completed by ``data`` (a bytes-like object), in order."""
        frames: List[Frame] = []
        raw = check_bytes(data, "data", 0, 1 << 62, **_ERR)
        with self._lock:         # execAsyncByteIn releases the GIL: one feeder at a time
            st, buf = self._state, self._buf
            for b in raw:
                if lib.execAsyncByteIn(b, st, buf):
                    frame = Frame(st.Node, st.SeqNo, bytes(ffi.buffer(buf, st.Length)),
                                  Status(st.Status))
                    log.debug("decoded %s", frame)
                    frames.append(frame)
        return frames


# ---- structure packing -----------------------------------------------------------

_CTYPES: Dict[str, Any] = {
    "u8": ctypes.c_uint8, "s8": ctypes.c_int8,
    "u16": ctypes.c_uint16, "s16": ctypes.c_int16,
    "u32": ctypes.c_uint32, "s32": ctypes.c_int32,
    "u64": ctypes.c_uint64, "s64": ctypes.c_int64,
    "f32": ctypes.c_float, "f64": ctypes.c_double,
    "bytes": ctypes.c_char,          # count = length; copied as is
}

FieldSpec = Union[Tuple[str, str], Tuple[str, str, int]]


class StructLayout:
    """A C structure described in Python, packed by the C core.

    ``fields`` lists ``(name, type)`` or ``(name, type, count)`` in member
    order; types are ``u8 s8 u16 s16 u32 s32 u64 s64 f32 f64`` and
    ``bytes`` (count = its length). The native layout (offsets, padding) is
    the platform C compiler's, as ``ctypes`` computes it; the descriptor
    handed to ``execPackDataEx`` is built from it, so the packed bytes are
    what a C program with the same struct sends::

        layout = StructLayout([("id", "u8"), ("raw", "u16"), ("delta", "s16", 3)])
        wire = layout.pack({"id": 1, "raw": 0x1234, "delta": [1, -1, 0]})
        layout.unpack(wire)["raw"] == 0x1234
    """

    def __init__(self, fields: Sequence[FieldSpec]) -> None:
        if isinstance(fields, (str, bytes)) or not isinstance(fields, Sequence):
            raise ExecTypeError(f"fields must be a sequence of tuples, not {type(fields).__name__}")
        if not fields:
            raise ExecValueError("a structure needs at least one field")
        specs: List[Tuple[str, str, int]] = []
        for f in fields:
            if not isinstance(f, tuple) or len(f) not in (2, 3):
                raise ExecValueError(f"field {f!r}: expected (name, type[, count])")
            name, kind = f[0], f[1]
            if not isinstance(name, str) or not name.isidentifier() or name.startswith("_"):
                raise ExecValueError(f"field name {name!r} must be an identifier")
            if not isinstance(kind, str):
                raise ExecTypeError(f"field {name!r}: type must be a str, not {type(kind).__name__}")
            count = check_int(f[2], f"field {name!r} count", 1, 0xFFFF, **_ERR) if len(f) == 3 else 1
            if kind not in _CTYPES:
                raise ExecValueError(f"field {name!r}: unknown type {kind!r} "
                                     f"(one of {' '.join(_CTYPES)})")
            if count < 1:
                raise ExecValueError(f"field {name!r}: count {count} < 1")
            specs.append((name, kind, count))
        names = [s[0] for s in specs]
        if len(set(names)) != len(names):
            raise ExecValueError("field names must be unique")
        ctype_fields = [(n, _CTYPES[k] * c if (c > 1 or k == "bytes") else _CTYPES[k])
                        for n, k, c in specs]
        self._struct: Any = type("ExecStruct", (ctypes.Structure,), {"_fields_": ctype_fields})
        self._specs = specs
        self.native_size = ctypes.sizeof(self._struct)
        if self.native_size > 0xFFFF:
            raise ExecValueError("structure larger than 65535 bytes")
        self._desc = ffi.new("struct execStructDef[]", len(specs) + 1)
        for i, (name, kind, count) in enumerate(specs):
            d = self._desc[i]
            d.Offset = getattr(self._struct, name).offset
            d.Size = ctypes.sizeof(_CTYPES[kind])
            d.Count = count
        self._desc[len(specs)].Offset = self.native_size   # terminator: Size 0
        self.packed_size = sum(ctypes.sizeof(_CTYPES[k]) * c for _, k, c in specs)

    @property
    def names(self) -> List[str]:
        return [s[0] for s in self._specs]

    def pack_native(self, native: BytesLike) -> bytes:
        """Native-layout bytes (e.g. a cffi/ctypes struct) -> packed big-endian."""
        native = check_bytes(native, "native", 0, 1 << 62, **_ERR)
        if len(native) != self.native_size:
            raise ExecValueError(f"{len(native)} bytes, the native structure has {self.native_size}")
        src = ffi.new("byte[]", native)
        out = ffi.new("byte[]", max(self.packed_size, 1))
        n = lib.execPackDataEx(out, src, self._desc)
        return bytes(ffi.buffer(out, n))

    def unpack_native(self, packed: BytesLike) -> bytes:
        """Packed big-endian -> native-layout bytes (padding zero)."""
        packed = check_bytes(packed, "packed", 0, 1 << 62, **_ERR)
        if len(packed) != self.packed_size:
            raise ExecValueError(f"{len(packed)} bytes, the packed structure has {self.packed_size}")
        src = ffi.new("byte[]", packed)
        out = ffi.new("byte[]", self.native_size)   # zeroed: padding stays 0
        n = lib.execUnPackDataEx(out, src, self._desc)
        return bytes(ffi.buffer(out, n))

    def pack(self, values: Mapping[str, Any]) -> bytes:
        """Field values (ints, floats, lists for arrays, bytes) -> packed bytes."""
        if not isinstance(values, Mapping):
            raise ExecTypeError(f"values must be a mapping, not {type(values).__name__}")
        missing = [n for n in self.names if n not in values]
        extra = [n for n in values if n not in self.names]
        if missing or extra:
            raise ExecValueError(f"missing fields {missing}, unknown fields {extra}")
        inst = self._struct()
        for name, kind, count in self._specs:
            v = values[name]
            try:
                if kind == "bytes":
                    v = check_bytes(v, f"field {name!r}", 0, count, **_ERR)
                    if len(v) > count:
                        raise ExecValueError(f"field {name!r}: {len(v)} bytes, room for {count}")
                    ctypes.memmove(ctypes.addressof(inst) + getattr(self._struct, name).offset,
                                   v, len(v))
                elif count > 1:
                    if isinstance(v, (str, bytes)) or not isinstance(v, Sequence):
                        raise ExecTypeError(f"field {name!r}: expected a sequence of {count}")
                    if len(v) != count:
                        raise ExecValueError(f"field {name!r}: {len(v)} items, expected {count}")
                    arr = getattr(inst, name)
                    for i, item in enumerate(v):
                        arr[i] = _checked(name, kind, item)
                else:
                    setattr(inst, name, _checked(name, kind, v))
            except (TypeError, OverflowError) as exc:
                raise ExecValueError(f"field {name!r}: {exc}") from None
        return self.pack_native(bytes(inst))

    def unpack(self, packed: BytesLike) -> Dict[str, Any]:
        """Packed bytes -> dict of field values (lists for arrays)."""
        inst = self._struct.from_buffer_copy(self.unpack_native(packed))
        out: Dict[str, Any] = {}
        for name, kind, count in self._specs:
            v = getattr(inst, name)
            if kind == "bytes":
                off = getattr(self._struct, name).offset
                out[name] = bytes(inst)[off:off + count]
            elif count > 1:
                out[name] = list(v)
            else:
                out[name] = v
        return out


def _checked(name: str, kind: str, value: Any) -> Any:
    """Range-check an integer (ctypes would silently wrap it)."""
    if kind[0] == "f":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ExecTypeError(f"field {name!r}: {value!r} is not a number")
        try:
            return float(value)
        except OverflowError:
            raise ExecValueError(f"field {name!r}: {value} does not fit a float") from None
    if not isinstance(value, int) or isinstance(value, bool):
        raise ExecTypeError(f"field {name!r}: {value!r} is not an int")
    bits = int(kind[1:])
    lo, hi = (0, (1 << bits) - 1) if kind[0] == "u" else (-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    if not lo <= value <= hi:
        raise ExecValueError(f"field {name!r}: {value} out of range {lo}..{hi} ({kind})")
    return value


# ---- engine ---------------------------------------------------------------------

@dataclass(frozen=True)
class MasterStats(Counters):
    """``execMasterStats``: counters since the master was opened."""

    transactions: int
    replies: int
    failures: int
    retries: int
    timeouts: int
    corrupt: int
    unexpected: int
    broadcasts: int
    tx_frames: int
    rx_frames: int


@dataclass(frozen=True)
class SlaveStats(Counters):
    """``execSlaveStats``: counters since the slave was opened."""

    processed: int
    resent: int
    broadcasts: int
    replies: int
    no_reply: int
    ignored: int
    corrupt: int
    rx_during_tx: int
    collisions: int
    rx_frames: int


_C = TypeVar("_C", bound=Counters)


def _reopen(handle: "Union[Master, Slave]", port_of: Callable[[Any], Any]) -> None:
    """fap_port_reopen on the port under a master's or a slave's handle."""
    with handle._using() as h:
        _raise_for(lib.fap_port_reopen(port_of(h)), "reopen", handle.path)


def _stats(handle: "Union[Master, Slave]", cls: Type[_C], ctype: str, get: Callable[..., Any]) -> _C:
    """A snapshot of a master's or a slave's counters: ``get(handle, ctype)`` as ``cls``."""
    st = ffi.new(ctype)
    handle._call(get, st)
    return stats_from_c(cls, st)


class _Steps:
    """One :meth:`Master.atransact` driven from the loop's callbacks: ``execMasterStep``
    runs in the port fd's reader callback (and in the timer's, at the attempt's
    deadline), so a reply that comes in several reads (~10 at 115200 on a paced
    link) wakes the task once, when the transaction ends, not once a read. The
    reader is the master's, kept from one transaction to the next
    (:meth:`Master._alisten`); the timer is one per attempt."""

    __slots__ = ("master", "loop", "args", "deadline", "done", "timer", "at")

    def __init__(self, master: "Master", reply: Any, reply_len: Any, deadline: Any) -> None:
        self.master = master
        self.loop = asyncio.get_running_loop()
        self.args = (reply, MAX_DATA, reply_len, deadline)
        self.deadline = deadline
        self.timer: Optional[asyncio.TimerHandle] = None
        self.at: Optional[int] = None        # the C deadline the timer is set for
        self.done: "asyncio.Future[int]" = self.loop.create_future()   # Step's last rc
        self._arm()

    def _arm(self) -> None:
        """The timer for the attempt's deadline (a retry moves it)."""
        at = self.deadline[0]
        if at != self.at:
            if self.timer is not None:
                self.timer.cancel()
            left = max(0.0, at / 1e9 - time.monotonic())   # both CLOCK_MONOTONIC
            self.timer = self.loop.call_later(left, self._expired)
            self.at = at

    def _expired(self) -> None:
        self.at = None                       # (a loop timer may fire a hair early: set anew)
        self.step()

    def step(self) -> None:
        if self.done.done():
            return
        try:
            rc = int(self.master._call(lib.execMasterStep, *self.args))
        except Exception as exc:             # ClosedError: closed from another thread
            self.done.set_exception(exc)
            return
        if rc != lib.EXEC_MASTER_MORE:
            self.done.set_result(rc)
            return
        self._arm()
        if self.master._aport is None:       # the reader was taken (await_readable)
            self.master._alisten(self)

    def fail(self, exc: BaseException) -> None:
        if not self.done.done():
            self.done.set_exception(exc)

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()


class Master(NativeHandle):
    """Exec async master on one port.

    ``timeout`` is per attempt (end of our frame to end of the reply);
    ``retries`` extra attempts repeat the frame with the same sequence
    number. Sequence numbers are kept per node (0, 1..255, 1..).

    Args:
        port: serial device path (or a :class:`~fap_py.vbus.VirtualBus` path), or
            a daemon's ``fapd:///path.sock`` / ``fapd://host:port`` (``fap serve``: the
            same calls, results and exceptions; a :class:`DaemonMaster` is returned).
        baudrate: line speed.
        timeout: seconds per attempt; ``None`` = the C engine's default
            (``execMasterOptionsInit``).
        retries: extra attempts after the first; ``None`` = the C default.
        rs485: :class:`fap_py.RS485` line options, as for FAP nodes
            (``echo_suppression=True`` on a bus that echoes our own bytes).

    Thread-safe; a context manager.
    """

    _kind = "exec async master"

    def __new__(cls, port: Any = None, *args: Any, **kwargs: Any) -> Any:
        from .serve._url import is_daemon_url

        if cls is Master and is_daemon_url(port):   # fapd://: the bus a daemon owns
            return DaemonMaster(port, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, port: Union[str, "os.PathLike[str]"], baudrate: int = 115200, *,
                 timeout: Optional[float] = None, retries: Optional[int] = None,
                 rs485: Optional[RS485] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None) -> None:
        super().__init__()
        if weight is not None or priority is not None or token is not None:
            raise ExecValueError(f"{port!r}: weight, priority and token are for a fapd:// URL "
                                 "(a bus shared through `fap serve`)")
        self._lock = threading.Lock()        # one transaction at a time
        self._alock: Optional[asyncio.Lock] = None   # the same among atransact tasks
        self._abufs: Optional[Tuple[Any, Any, Any]] = None   # atransact's reply, length, deadline
        self._aport: Optional[Tuple[asyncio.AbstractEventLoop, int, "asyncio.Future[bool]"]] = None
        self._asteps: Optional[_Steps] = None   # the atransact the reader serves
        self._areopened = False              # reopen() since the reader was added
        self._ainflight = 0                  # atransact calls between Begin and their end
        self.path = check_path(port)
        popts = port_options(baudrate, rs485)
        mopts = ffi.new("execMasterOptions *")
        lib.execMasterOptionsInit(mopts)     # C's defaults are the only defaults
        if timeout is not None:
            mopts.reply_timeout_us = self._timeout_us(timeout)
        if retries is not None:
            mopts.retries = self._retries_checked(retries)
        self._retries = int(mopts.retries)
        out = ffi.new("execMaster **")
        raw = os.fsencode(self.path)

        def open_with(cancel_fd: int) -> int:   # a network open: Ctrl-C ends it (mopts.cancel_fd)
            mopts.cancel_fd = cancel_fd
            return int(lib.execMasterOpen(out, raw, popts, mopts))

        _raise_for(open_interruptibly(raw, open_with,
                                      lambda rc: rc == 0 and lib.execMasterClose(out[0])),
                   "open", self.path)
        self._adopt(out[0])
        self._tap = _trace.attach(lib.execMasterSetTrace, self._h, "exec", self.path)
        self._reply = ffi.new("byte[]", MAX_DATA)
        self._reply_len = ffi.new("word *")
        log.info("exec async master on %s", self.path)

    def _label(self) -> str:
        return f"exec async master on {self.path}"

    def _release(self, h: Any) -> None:
        lib.execMasterClose(h)

    def _interrupt(self) -> None:
        # a transact in another thread returns -ECANCELED (ClosedError) at once
        # instead of waiting out its timeout and retries
        h = self._h
        if h is not None:
            lib.execMasterStop(h)

    def _fd(self, h: Any) -> int:
        return int(lib.fap_port_fd(lib.execMasterPort(h)))

    @staticmethod
    def _timeout_us(timeout: Any) -> int:
        t = check_seconds(timeout, "timeout", lo=0.0, lo_open=True, hi=3600.0, **_ERR)
        return max(1, int(round(t * 1e6)))

    @staticmethod
    def _retries_checked(retries: Any) -> int:
        return check_int(retries, "retries", 0, 1000, **_ERR)

    def set_timeout(self, timeout: float, retries: Optional[int] = None) -> None:
        """Change the per-attempt timeout (s) and, if given, the retries."""
        us = self._timeout_us(timeout)
        r = self._retries if retries is None else self._retries_checked(retries)
        with self._lock, self._using() as m:
            _raise_for(lib.execMasterSetTimeout(m, us, r), "set_timeout")
            self._retries = r

    def transact(self, node: int, data: BytesLike = b"") -> bytes:
        """Poll ``node`` (1..254) with ``data``; return its reply.

        Raises :class:`NoReplyError` / :class:`CorruptReplyError` when every
        attempt failed (the next message to that node then carries SeqNo 0).
        """
        _check_node(node)
        payload = _check_data(data)
        self._not_inside_atransact()
        with self._lock, self._using() as m:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("-> node %d seq %d %s", node, lib.execMasterNextSeq(m, node), payload.hex())
            rc = lib.execMasterTransact(m, node, payload, len(payload), self._reply, MAX_DATA,
                                        self._reply_len)
            _raise_for(rc, f"node {node}", self.path)
            reply = bytes(ffi.buffer(self._reply, self._reply_len[0]))
        if log.isEnabledFor(logging.DEBUG):
            log.debug("<- node %d %s", node, reply.hex())
        return reply

    def _not_inside_atransact(self) -> None:
        """The blocking calls wait in C for an atransact in flight; in that
        atransact's own loop thread this would never end: refuse."""
        if not self._ainflight:
            return
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return                           # another thread: waiting is fine
        raise ExecAsyncError(f"{self._label()}: an atransact is in flight in this event loop; "
                             "use atransact/abroadcast there")

    async def atransact(self, node: int, data: BytesLike = b"") -> bytes:
        """``await``-able :meth:`transact`, driven by the running asyncio loop.

        The C engine's non-blocking steps (``execMasterBegin`` /
        ``execMasterStep``: the same sequence numbers, retries, trace hook
        and stats as :meth:`transact`) run in the loop's thread, each step
        when the port fd turns readable (one ``loop.add_reader`` for the
        whole transaction) or the attempt's deadline passes (a loop timer);
        the task waits once, for the transaction's end. No worker thread. Calls on one master are serialised; different masters
        run concurrently.
        Cancelling ends the transaction as a failure (the next message to
        ``node`` carries SeqNo 0) and leaves the master usable; a close()
        from another task or thread raises :class:`~fap_py.errors.ClosedError`.
        """
        _check_node(node)
        payload = _check_data(data)
        if self._alock is None:
            self._alock = asyncio.Lock()
        if self._abufs is None:              # one set of buffers: used under _alock only
            self._abufs = (ffi.new("byte[]", MAX_DATA), ffi.new("word *"), ffi.new("int64_t *"))
        reply, reply_len, deadline = self._abufs
        what = f"node {node}"
        async with self._alock:
            log.debug("-> node %d (async) %s", node, payload.hex())
            rc = int(self._call(lib.execMasterBegin, node, payload, len(payload), deadline))
            if rc == -errno.EBUSY:
                raise ExecAsyncError(f"{self._label()}: another atransact is in flight "
                                     "(from another event loop)")
            _raise_for(rc, what, self.path)
            self._ainflight += 1
            over = False
            steps: Optional[_Steps] = None
            try:
                steps = _Steps(self, reply, reply_len, deadline)
                self._alisten(steps)
                rc = await steps.done
                over = True
                _raise_for(rc, what, self.path)
                out = bytes(ffi.buffer(reply, reply_len[0]))
                log.debug("<- node %d (async) %s", node, out.hex())
                return out
            finally:
                self._asteps = None
                if steps is not None:
                    steps.close()
                self._ainflight -= 1
                if not over:                 # cancelled, closed or interrupted mid-way
                    try:
                        self._call(lib.execMasterAbort)
                    except ClosedError:
                        pass

    # The port fd's reader for atransact, kept from one transaction to the next (adding
    # and removing it each time, two epoll_ctl calls and asyncio's bookkeeping, was a
    # tenth of the daemon's time). It is registered with the handle's asyncio waits,
    # so a close() from any thread detaches it and fails the transaction in flight.

    def _alisten(self, steps: _Steps) -> None:
        """Make ``steps`` the transaction the reader serves; add the reader if needed."""
        loop = steps.loop
        port = self._aport
        if port is not None and (port[0] is not loop or self._areopened):
            self._adetach()                  # (a reopened port: another fd, or the number reused)
            port = None
        if port is None:
            self._areopened = False
            fd = int(self._call(self._fd))   # ClosedError once closed
            gone: "asyncio.Future[bool]" = loop.create_future()   # failed by close()
            gone.add_done_callback(self._agone)
            with self._hlock:
                self._async_waits[gone] = fd
            loop.add_reader(fd, self._areadable)
            self._aport = (loop, fd, gone)
        self._asteps = steps

    def _areadable(self) -> None:
        steps = self._asteps
        if steps is not None:
            steps.step()
        else:                                # bytes between transactions: level-triggered,
            self._adetach()                  # it would fire every loop turn; the next Begin drops them

    def _adetach(self) -> None:
        """Remove atransact's reader (from its loop's thread, or with that loop stopped)."""
        port, self._aport = self._aport, None
        if port is None:
            return
        loop, fd, gone = port
        with self._hlock:
            registered = self._async_waits.pop(gone, None) is not None
        if not registered or loop.is_closed():
            return
        try:
            running: Optional[asyncio.AbstractEventLoop] = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop or not loop.is_running():
            loop.remove_reader(fd)
        else:
            loop.call_soon_threadsafe(loop.remove_reader, fd)

    def _agone(self, f: "asyncio.Future[bool]") -> None:
        """close() detached the reader: forget it, fail the transaction in flight."""
        port = self._aport
        if port is not None and port[2] is f:
            self._aport = None
        exc = None if f.cancelled() else f.exception()
        steps = self._asteps
        if steps is not None:
            steps.fail(exc or self._closed_error())

    async def await_readable(self, timeout: Optional[float] = None) -> bool:
        """As :meth:`NativeHandle.await_readable` (atransact's reader, if kept, first
        leaves the fd to it)."""
        self._adetach()
        return await super().await_readable(timeout)

    def fileno(self) -> int:
        """As :meth:`NativeHandle.fileno`; asked in the loop that keeps atransact's
        reader, that reader leaves the fd first (the caller may add its own there)."""
        port = self._aport
        if port is not None and self._asteps is None:
            try:
                here = asyncio.get_running_loop() is port[0]
            except RuntimeError:
                here = False
            if here:
                self._adetach()
        return super().fileno()

    async def abroadcast(self, data: BytesLike = b"") -> None:
        """:meth:`broadcast` from a coroutine, in turn with this master's
        atransact calls (a broadcast only writes: it never waits for a reply)."""
        if self._alock is None:
            self._alock = asyncio.Lock()
        async with self._alock:
            self.broadcast(data)

    def broadcast(self, data: BytesLike = b"") -> None:
        """Send ``data`` to every slave (node 255); nobody answers."""
        payload = _check_data(data)
        self._not_inside_atransact()
        with self._lock, self._using() as m:
            log.debug("-> broadcast %s", payload.hex())
            _raise_for(lib.execMasterBroadcast(m, payload, len(payload)), "broadcast", self.path)

    def next_seq(self, node: int) -> int:
        """The sequence number the next message to ``node`` will carry."""
        _check_node(node, allow_broadcast=True)
        with self._lock:
            return int(self._call(lib.execMasterNextSeq, node))

    def reopen(self) -> None:
        """Open the device again (after it vanished: a USB unplug, say)."""
        with self._lock:
            _reopen(self, lib.execMasterPort)
            self._areopened = True           # atransact's reader: add it again

    def reset_sequence(self) -> None:
        """Start again from sequence number 0 for every node (a master restart)."""
        with self._lock:
            self._call(lib.execMasterResetSequence)

    @property
    def stats(self) -> MasterStats:
        """A snapshot of the counters (``execMasterStats``)."""
        return _stats(self, MasterStats, "execMasterStats *", lib.execMasterGetStats)

    def close(self) -> None:
        """Close the port (waits for a transaction in progress). Idempotent."""
        super().close()


#: this module's exceptions by name, as a daemon's answer names them
_WIRE_ERRORS = {c.__name__: (lambda e, c=c: c(str(e.get("message", "")))) for c in
                (ExecAsyncError, ExecValueError, ExecTypeError, NoReplyError, CorruptReplyError)}


class DaemonMaster(DaemonLife):
    """An exec async master on a bus a daemon owns (``fap serve``, docs/daemon.md):
    what ``Master("fapd://...")`` returns. The same calls, results and exceptions as
    :class:`Master`; each transaction (with its retries and sequence number) runs on
    the daemon's engine, atomically among its clients. ``weight``, ``priority`` and
    ``token`` override the URL's query (``?weight=3``, ``?token=``, ``$FAP_SERVE_TOKEN``);
    ``baudrate`` and ``rs485`` are the daemon's (given ones are ignored). Thread-safe:
    several threads (or tasks) may each have a transaction queued.
    """

    _kind = "exec async master"

    def __init__(self, port: Union[str, "os.PathLike[str]"], baudrate: int = 115200, *,
                 timeout: Optional[float] = None, retries: Optional[int] = None,
                 rs485: Optional[RS485] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None) -> None:
        from .serve._client import Connection, PerLoop

        port_options(baudrate, rs485)            # checked as for a device (the daemon's are used)
        self._timeout = None if timeout is None else Master._timeout_us(timeout) / 1e6
        self._retries = None if retries is None else Master._retries_checked(retries)
        self._counts: Dict[str, int] = dict.fromkeys((f.name for f in dataclasses.fields(MasterStats)), 0)
        self._clock = threading.Lock()
        self._hello: Dict[str, Any] = {"weight": weight, "priority": priority, "token": token}
        self._conn = Connection(port, protocol="exec", name="exec master", errors=_WIRE_ERRORS,
                                **self._hello)
        self.path = self._conn.url
        self._aconn = PerLoop(self.path, protocol="exec", name="exec master", errors=_WIRE_ERRORS,
                              **self._hello)
        self.closed = False
        log.info("exec async master on %s", self.path)

    def _fields(self, node: int, data: bytes) -> Dict[str, Any]:
        out: Dict[str, Any] = {"node": node, "data": data.hex()}
        if self._timeout is not None:
            out["timeout"] = self._timeout
        if self._retries is not None:
            out["retries"] = self._retries
        return out

    def _add(self, answer: Dict[str, Any]) -> None:
        with self._clock:
            for k, v in (answer.get("stats") or {}).items():
                if k in self._counts and isinstance(v, int):
                    self._counts[k] += v

    def _ask(self, op: str, **fields: Any) -> Dict[str, Any]:
        if self.closed:
            raise ClosedError(f"exec async master on {self.path} is closed")
        try:
            answer = self._conn.call(op, **fields)
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise
        self._add(answer)
        return answer

    async def _aask(self, op: str, **fields: Any) -> Dict[str, Any]:
        if self.closed:
            raise ClosedError(f"exec async master on {self.path} is closed")
        conn = await self._aconn.get()
        try:
            answer = await conn.call(op, **fields)
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise
        except asyncio.CancelledError:
            if op == "transact":   # counted as a direct master counts a cancelled one
                self._add({"stats": {"transactions": 1, "failures": 1}})
            raise
        self._add(answer)
        return answer

    def set_timeout(self, timeout: float, retries: Optional[int] = None) -> None:
        """The per-attempt timeout (s) and, if given, the retries of later transactions."""
        self._timeout = Master._timeout_us(timeout) / 1e6
        if retries is not None:
            self._retries = Master._retries_checked(retries)

    def transact(self, node: int, data: BytesLike = b"") -> bytes:
        """As :meth:`Master.transact`, through the daemon."""
        _check_node(node)
        payload = _check_data(data)
        return bytes.fromhex(self._ask("transact", **self._fields(node, payload))["data"])

    async def atransact(self, node: int, data: BytesLike = b"") -> bytes:
        """As :meth:`Master.atransact`: an asyncio connection, no thread."""
        _check_node(node)
        payload = _check_data(data)
        return bytes.fromhex((await self._aask("transact", **self._fields(node, payload)))["data"])

    def broadcast(self, data: BytesLike = b"") -> None:
        """As :meth:`Master.broadcast`."""
        self._ask("broadcast", data=_check_data(data).hex())

    async def abroadcast(self, data: BytesLike = b"") -> None:
        """As :meth:`Master.abroadcast`."""
        await self._aask("broadcast", data=_check_data(data).hex())

    def next_seq(self, node: int) -> int:
        """The sequence number the daemon's next message to ``node`` will carry
        (another client may take it first)."""
        _check_node(node, allow_broadcast=True)
        return int(self._ask("next_seq", node=node)["seq"])

    def reopen(self) -> None:
        """Nothing to do: the daemon reopens the device itself (and says so)."""

    def reset_sequence(self) -> None:
        """Refused: the sequence numbers are the daemon's, shared by its clients."""
        raise ExecAsyncError(f"{self.path}: the daemon owns the sequence numbers; "
                             "restart the daemon to reset them")

    @property
    def stats(self) -> MasterStats:
        """This client's share of the engine's counters (what its transactions did)."""
        with self._clock:
            return MasterStats(**self._counts)

    def fileno(self) -> int:
        raise ExecValueError(f"{self.path}: a daemon connection has no port fd")

    def _closed(self) -> None:
        self.closed = True

    def __repr__(self) -> str:
        return f"<DaemonMaster {self.path}{' closed' if self.closed else ''}>"


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


__all__ = [
    "RS485", "RS485Mode", "BROADCAST", "NODE_MIN", "NODE_MAX", "DEFAULT_BAUD", "MAX_DATA", "MAX_FRAME", "CorruptReplyError", "DaemonMaster", "Decoder", "ExecAsyncError",
    "ExecTypeError", "ExecValueError", "Frame", "Master", "MasterStats", "NoReplyError", "Request",
    "ServeResult", "Slave", "SlaveStats", "Status", "StructLayout", "encode",
]
