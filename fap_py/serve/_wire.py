"""The client protocol's framing (docs/daemon.md): a 4-byte big-endian length, then
that many bytes of UTF-8 JSON holding one object. Private.

Byte strings travel as lowercase hex. One rule for both ends: :func:`pack` and
:func:`unpack`; :func:`read_message` for asyncio streams (with a deadline for
the body, so a half-sent message cannot hold a reader forever).
"""
from __future__ import annotations

import asyncio
import json
import struct
from typing import Any, Dict, Optional

from ._errors import ProtocolError

#: the protocol version: a daemon refuses another major, a minor only adds fields
VERSION = (1, 0)
#: the largest message either side sends or accepts (bytes of JSON)
MAX_MESSAGE = 64 * 1024
_HEADER = struct.Struct(">I")
HEADER_SIZE = _HEADER.size


def pack(obj: Dict[str, Any]) -> bytes:
    """One message: header + compact JSON."""
    body = json.dumps(obj, separators=(",", ":")).encode()
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


async def read_message(reader: asyncio.StreamReader, body_timeout: Optional[float],
                       first_timeout: Optional[float] = None) -> Optional[Dict[str, Any]]:
    """The next message, None at a clean end of stream (between messages).

    ``first_timeout``: how long to wait for a header (None: forever);
    ``body_timeout``: how long the rest may take once a header started.
    Raises ProtocolError (bad length, bad JSON, stream cut mid-message) and
    asyncio.TimeoutError (a message started and not finished in time).
    """
    try:
        first = await asyncio.wait_for(reader.read(1), first_timeout) if first_timeout \
            else await reader.read(1)
    except ConnectionError:
        return None
    if not first:
        return None
    try:
        rest = await asyncio.wait_for(reader.readexactly(HEADER_SIZE - 1), body_timeout)
        n = body_size(first + rest)
        body = await asyncio.wait_for(reader.readexactly(n), body_timeout)
    except asyncio.IncompleteReadError:
        raise ProtocolError("stream ended inside a message") from None
    except ConnectionError:
        raise ProtocolError("connection reset inside a message") from None
    return unpack(body)


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
