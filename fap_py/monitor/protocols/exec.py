"""The monitor's exec async plug-in: execAsyncByteIn from the C codec table."""
from __future__ import annotations

from typing import Optional, Tuple

from ... import _protocols
from ..decoders import CodecDecoder, Decoder, Event, check_event

NAME = "exec"
FIELDS = ("node", "seq", "data")
#: the Wireshark dissector's name and filter prefix ("exec" is Wireshark's rexec)
DISSECTOR = "execasync"

#: request and answer look alike (no direction bit): the statistics take a frame
#: repeating the pending request byte for byte as its retry, not its answer
DIRECTIONLESS = True
#: the broadcast node (no answer), from the protocol table
_BROADCAST = _protocols.get(NAME).broadcast

__all__ = ["DIRECTIONLESS", "DISSECTOR", "FIELDS", "NAME", "decoder", "pair", "summary"]


def decoder(baud: int = 0) -> Decoder:
    """exec async's receiver decoder (it has no inter-byte gap: ``baud`` is unused)."""
    return CodecDecoder(NAME, baud)   # the C row's fields (node, seq) and data, as they are


def summary(event: Event) -> str:
    f = check_event(event, NAME).fields or {}
    return f"node {f['node']:>3} seq {f['seq']:>3}"


def pair(event: Event, asked: object = None) -> Tuple[object, Optional[str], object]:
    """Request and answer carry the same node and sequence number: the frame that
    repeats the pending request's (node, seq) answers it. A broadcast has no answer."""
    f = check_event(event, NAME).fields or {}
    node = f["node"]
    if node == _BROADCAST:
        return node, None, None
    key = (node, f["seq"])
    return node, "ans" if asked == key else "req", key
