"""The monitor's FAP plug-in: the engine's stream decoder from the C codec table."""
from __future__ import annotations

from typing import Dict, Optional, Tuple

from ..._validate import U32, check_int
from ...fap.types import MASTER_ID
from ..decoders import CodecDecoder, Decoder, Event, _text_field, check_event

NAME = "fap"
FIELDS = ("msg", "msg_name", "dst", "src", "data")

__all__ = ["FIELDS", "NAME", "decoder", "label", "pair", "summary"]


def _fields(values: Tuple[int, ...], data: bytes, name: Optional[str]) -> Dict[str, object]:
    msg, dst, src = values
    return {"msg": msg, "msg_name": name or str(msg), "dst": dst, "src": src, "data": data}


def decoder(baud: int = 0, gap_ns: int = 0) -> Decoder:
    """FAP's receiver decoder; ``baud`` (0 unknown) or ``gap_ns`` sets its inter-byte gap."""
    return CodecDecoder(NAME, check_int(baud, "baud", 0, U32), gap_ns, fields=_fields)


def summary(event: Event) -> str:
    f = check_event(event, NAME).fields or {}
    return f"{f['msg_name']:<9} {f['src']:>2} -> {f['dst']:<2}"


def label(event: Event) -> Optional[str]:
    """The message type (SEND_DATA, DATA, ...)."""
    return _text_field(event, NAME, "msg_name")


def pair(event: Event, asked: object = None) -> Tuple[object, Optional[str], object]:
    """The master polls a slave (a request to dst); the slave's frame answers it."""
    f = check_event(event, NAME).fields or {}
    if f["src"] == MASTER_ID:
        return f["dst"], "req", f["dst"]
    return f["src"], "ans", f["src"]

