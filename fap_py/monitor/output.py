"""How records are shown: one JSON object per line, or one human line."""
from __future__ import annotations

import json
from typing import Dict, Optional, cast

from .._validate import check_bytes
from ..errors import InvalidTypeError
from ..g485.codec import MASTER_ADDRESS
from .core import T_MAX, Record, _check_time
from .decoders import FIELDS, G485_PREAMBLE


def to_json(rec: Record) -> Dict[str, object]:
    """The documented JSON object of a record (docs/monitor.md).

    Common keys: protocol, t, port, ok, error, frame; then the protocol's
    fields (null for a bad frame or garbage). Bytes are lower-case hex.
    """
    if not isinstance(rec, Record):
        raise InvalidTypeError(f"rec must be a Record, not {type(rec).__name__}")
    ev = rec.event
    out: Dict[str, object] = {
        "protocol": ev.protocol,
        "t": None if rec.t is None else round(rec.t, 6),
        "port": rec.port,
        "ok": ev.error is None,
        "error": ev.error,
        "frame": ev.raw.hex(),
    }
    fields = ev.fields
    for name in FIELDS[ev.protocol]:
        value = fields.get(name) if fields else None
        out[name] = value.hex() if isinstance(value, (bytes, bytearray)) else value
    return out


def json_line(rec: Record) -> str:
    return json.dumps(to_json(rec), separators=(",", ":"))


def printable(data: bytes) -> str:
    """The bytes as ASCII, a dot for each byte that does not print."""
    data = check_bytes(data, "data", 0, 2**62)
    return "".join(chr(b) if 32 <= b < 127 else "." for b in data)


def _who(rec: Record) -> str:
    f = rec.fields or {}
    p = rec.protocol
    if p == "fap":
        return f"{f['msg_name']:<9} {f['src']:>2} -> {f['dst']:<2}"
    if p == "exec":
        return f"node {f['node']:>3} seq {f['seq']:>3}"
    if p == "mikroc":
        return f"{'master ->' if f['from_master'] else 'slave  <-'} {f['address']:>3}"
    if f["packet"] == G485_PREAMBLE:
        return f"{f['packet']} master"
    rw = "R" if f["rw"] else "W"
    if f["address"] == MASTER_ADDRESS:      # a reply: from the device the last request asked
        device = "?" if f.get("device") is None else f["device"]
        who = f"{device} -> master"
    else:
        who = f"master -> {f['address']}"
    return f"{f['packet']} {who} {rw} pid 0x{f['pid']:02x}"


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
        body = f"{_who(rec)}  [{len(data)}] {data.hex(' ')}  |{printable(data)}|" if data \
            else f"{_who(rec)}  [0]"
        return f"{t} {port} {rec.protocol:<6} {body}"
    return f"{t} {port} {rec.protocol:<6} !! {rec.error:<9} [{len(rec.raw)}] {rec.raw.hex(' ')}"


__all__ = ["human_line", "json_line", "printable", "to_json"]
