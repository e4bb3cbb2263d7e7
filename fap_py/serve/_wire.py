"""The client protocol's framing (docs/daemon.md): a 4-byte big-endian length, then
that many bytes of UTF-8 JSON holding one object. Private.

Byte strings travel as lowercase hex. One rule for both ends: :func:`pack` and
:func:`unpack`; :class:`MessageReader` for asyncio streams (with a deadline for
the body, so a half-sent message cannot hold a reader forever).
"""
from __future__ import annotations

import asyncio
import json
import struct
import sys
from typing import Any, Dict, Optional

from ._errors import ProtocolError

#: the protocol version: a daemon refuses another major, a minor only adds fields
VERSION = (1, 0)
#: the largest message either side sends or accepts (bytes of JSON)
MAX_MESSAGE = 64 * 1024
_HEADER = struct.Struct(">I")
HEADER_SIZE = _HEADER.size
#: one encoder (json.dumps with separators builds a new one per call)
_ENCODE = json.JSONEncoder(separators=(",", ":")).encode


def pack(obj: Dict[str, Any]) -> bytes:
    """One message: header + compact JSON."""
    body = _ENCODE(obj).encode()
    if len(body) > MAX_MESSAGE:
        raise ProtocolError(f"message of {len(body)} bytes over the limit of {MAX_MESSAGE}")
    return _HEADER.pack(len(body)) + body


def body_size(header: bytes) -> int:
    """The length a header announces; ProtocolError if over :data:`MAX_MESSAGE` or zero."""
    (n,) = _HEADER.unpack(header)
    if not 0 < n <= MAX_MESSAGE:
        raise ProtocolError(f"message length {n} outside 1..{MAX_MESSAGE}")
    return n


def unpack(body: bytes) -> Dict[str, Any]:
    """The object a body holds; ProtocolError for bad UTF-8 / JSON / a non-object."""
    try:
        obj = json.loads(body.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ProtocolError(f"message is not UTF-8 JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise ProtocolError(f"message is a JSON {type(obj).__name__}, not an object")
    return obj


#: bytes asked of the stream at a time: whatever is buffered, up to one largest message
_CHUNK = MAX_MESSAGE + HEADER_SIZE


class MessageReader:
    """The messages of one asyncio stream, in order.

    The stream is read in chunks and every complete message in the buffer is
    taken without waiting again, so a message costs one ``await`` at most (three
    ``readexactly`` calls each under ``wait_for`` cost a task apiece on Python
    3.11 and were a tenth of the daemon's time). ``body_timeout`` bounds how long
    a started message may take to complete (a half-sent message cannot hold a
    reader forever); between messages the reader waits as long as it is told.
    """

    def __init__(self, reader: asyncio.StreamReader, body_timeout: Optional[float]) -> None:
        self._reader = reader
        self._body_timeout = body_timeout
        self._buf = bytearray()
        self._started = 0.0              # when the buffered part of a message came

    def _take(self) -> Optional[Dict[str, Any]]:
        buf = self._buf
        if len(buf) < HEADER_SIZE:
            return None
        n = body_size(bytes(buf[:HEADER_SIZE]))
        if len(buf) < HEADER_SIZE + n:
            return None
        body = bytes(buf[HEADER_SIZE:HEADER_SIZE + n])
        del buf[:HEADER_SIZE + n]
        return unpack(body)

    async def next(self, first_timeout: Optional[float] = None) -> Optional[Dict[str, Any]]:
        """The next message, None at a clean end of stream (between messages).

        ``first_timeout``: how long to wait for a message to start (None: forever).
        Raises ProtocolError (bad length, bad JSON, stream cut mid-message) and
        asyncio.TimeoutError (a message started and not finished in time).
        """
        loop = asyncio.get_running_loop()
        while True:
            msg = self._take()
            if msg is not None:
                if self._buf:            # the next one began in the same chunk
                    self._started = loop.time()
                return msg
            inside = bool(self._buf)
            try:
                if inside and self._body_timeout is not None:
                    left = self._started + self._body_timeout - loop.time()
                    if left <= 0:
                        raise asyncio.TimeoutError
                    chunk = await _read_within(self._reader, left)
                elif not inside and first_timeout:
                    chunk = await _read_within(self._reader, first_timeout)
                else:
                    chunk = await self._reader.read(_CHUNK)
            except ConnectionError:
                if inside:
                    raise ProtocolError("connection reset inside a message") from None
                return None
            if not chunk:
                if inside:
                    raise ProtocolError("stream ended inside a message")
                return None
            if not inside:
                self._started = loop.time()
            self._buf += chunk


if sys.version_info >= (3, 11):
    async def _read_within(reader: asyncio.StreamReader, seconds: float) -> bytes:
        """A chunk, or asyncio.TimeoutError after ``seconds``. Not ``wait_for``: on 3.11 it
        loses a cancellation that comes as the read completes, and a reader task cancelled
        at its loop's end then reads on forever (seen: asyncio.run() hung closing a client)."""
        async with asyncio.timeout(seconds):
            return await reader.read(_CHUNK)
else:  # pragma: no cover - 3.9/3.10 have no asyncio.timeout
    async def _read_within(reader: asyncio.StreamReader, seconds: float) -> bytes:
        return await asyncio.wait_for(reader.read(_CHUNK), seconds)


def hex_field(obj: Dict[str, Any], key: str, most: int, *, default: Optional[bytes] = b"") -> bytes:
    """``obj[key]`` as bytes from hex, at most ``most`` bytes; ProtocolError otherwise."""
    text = obj.get(key)
    if text is None:
        if default is None:
            raise ProtocolError(f"field {key!r} is missing")
        return default
    if not isinstance(text, str):
        raise ProtocolError(f"field {key!r} must be a hex string")
    try:
        data = bytes.fromhex(text)
    except ValueError:
        raise ProtocolError(f"field {key!r} is not hex") from None
    if len(data) > most:
        raise ProtocolError(f"field {key!r}: {len(data)} bytes, at most {most}")
    return data


def num_field(obj: Dict[str, Any], key: str, lo: float, hi: float, default: Any = None,
              *, integer: bool = False) -> Any:
    """A number field within lo..hi (an int when ``integer``); ProtocolError otherwise."""
    v = obj.get(key, default)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
        raise ProtocolError(f"field {key!r} must be {'an integer' if integer else 'a number'}")
    if not lo <= v <= hi:
        raise ProtocolError(f"field {key!r} must be {lo}..{hi}, not {v}")
    return v
