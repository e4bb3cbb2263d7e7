"""The exec async frame codec (the C one, no I/O) and the protocol's constants."""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from enum import IntEnum
from typing import List, Union

from .._native import ffi, lib
from .._validate import check_bytes, check_int
from ..rs485 import DEFAULT_BAUD as _DEFAULT_BAUD
from .errors import _ERR

log = logging.getLogger("fap_py.execasync")   # one logger for the package (as before the split)

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
