"""The monitor's mikroC RS-485 plug-in: mikrocRS485_DecoderFeed from the C codec table."""
from __future__ import annotations

from typing import Dict, Optional, Tuple

from ..decoders import CodecDecoder, Decoder, Event, check_event

NAME = "mikroc"
FIELDS = ("address", "from_master", "data")

__all__ = ["FIELDS", "NAME", "decoder", "pair", "summary"]


def _fields(values: Tuple[int, ...], data: bytes, name: Optional[str]) -> Dict[str, object]:
    address, from_master = values
    return {"address": address, "from_master": bool(from_master), "data": data}


def decoder(baud: int = 0) -> Decoder:
    """mikroC's receiver decoder (it has no inter-byte gap: ``baud`` is unused)."""
    return CodecDecoder(NAME, baud, fields=_fields)


def summary(event: Event) -> str:
    f = check_event(event, NAME).fields or {}
    return f"{'master ->' if f['from_master'] else 'slave  <-'} {f['address']:>3}"


def pair(event: Event, asked: object = None) -> Tuple[object, Optional[str], object]:
    """DATALEN's master bit tells a request from an answer; both carry the slave's address."""
    f = check_event(event, NAME).fields or {}
    return f["address"], "req" if f["from_master"] else "ans", f["address"]
