"""How records are shown: one JSON object per line, or one human line."""
from __future__ import annotations

import json
from typing import Dict, Optional, cast

from .._validate import check_bytes
from ..errors import InvalidTypeError
from .core import T_MAX, Record, _check_time
from .decoders import plugin


def to_json(rec: Record) -> Dict[str, object]:
    """The documented JSON object of a record (docs/monitor.md).

    Common keys: event (``"frame"``), protocol, t, port, ok, error, frame; then the protocol's
    fields (null for a bad frame or garbage). Bytes are lower-case hex.
    """
    if not isinstance(rec, Record):
        raise InvalidTypeError(f"rec must be a Record, not {type(rec).__name__}")
    ev = rec.event
    out: Dict[str, object] = {
        "event": "frame",            # every record, good or bad (``ok``, ``error`` tell)
        "protocol": ev.protocol,
        "t": None if rec.t is None else round(rec.t, 6),
        "port": rec.port,
        "ok": ev.error is None,
        "error": ev.error,
        "frame": ev.raw.hex(),
    }
    fields = ev.fields
    for name in plugin(ev.protocol).FIELDS:
        value = fields.get(name) if fields else None
        out[name] = value.hex() if isinstance(value, (bytes, bytearray)) else value
    return out


def json_line(rec: Record) -> str:
    return json.dumps(to_json(rec), separators=(",", ":"))


def printable(data: bytes) -> str:
    """The bytes as ASCII, a dot for each byte that does not print."""
    data = check_bytes(data, "data", 0, 2**62)
    return "".join(chr(b) if 32 <= b < 127 else "." for b in data)


def human_line(rec: Record, t0: Optional[float] = None) -> str:
    """timestamp, sender port, protocol, addresses and message, payload hex |printable|."""
    if not isinstance(rec, Record):
        raise InvalidTypeError(f"rec must be a Record, not {type(rec).__name__}")
    if t0 is not None:
        _check_time(t0, "t0", 0.0, 2.0 * T_MAX)
    t = "         -" if rec.t is None else f"{rec.t - (t0 or 0.0):10.6f}"
    port = "  " if rec.port is None else f"p{rec.port}"
    if rec.ok:
        data = cast(bytes, (rec.fields or {}).get("data") or b"")
        who = plugin(rec.protocol).summary(rec.event)
        body = f"{who}  [{len(data)}] {data.hex(' ')}  |{printable(data)}|" if data \
            else f"{who}  [0]"
        return f"{t} {port} {rec.protocol:<6} {body}"
    return f"{t} {port} {rec.protocol:<6} !! {rec.error:<9} [{len(rec.raw)}] {rec.raw.hex(' ')}"


__all__ = ["human_line", "json_line", "printable", "to_json"]
