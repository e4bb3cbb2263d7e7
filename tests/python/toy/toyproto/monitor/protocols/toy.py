"""The toy protocol's monitor plug-in (tests only): decoder, fields, summary, pairing, label.

Found by name through the protocol table (``toyproto.table.TOY``: package ``toyproto``), exactly
as fap_py finds ``fap_py.monitor.protocols.<name>``: the monitor needs no edit to decode it. The
frame check is the binding's own Decoder's (a candidate frame is handed to a fresh one); this
plug-in only tells the monitor where each frame lies in the stream.
"""
from __future__ import annotations

from typing import Dict, List, Optional, Tuple

from fap_py._validate import U32, check_int
from fap_py.monitor.decoders import Decoder, Event, check_event
from toyproto import binding

NAME = "toy"
FIELDS = ("node", "reply", "data")

__all__ = ["FIELDS", "NAME", "ToyDecoder", "decoder", "pair", "summary"]

_HEADER = 3            # START, node, len: the length is known from here on
_OVERHEAD = _HEADER + 1


class ToyDecoder(Decoder):
    """Good frames, rejected candidates ("length", "check", resuming one byte later)
    and garbage, with their stream offsets."""

    name = NAME

    def __init__(self) -> None:
        self._held = bytearray()
        self._offset = 0                 # stream offset of _held[0]

    def _take(self, n: int, error: Optional[str], fields: Optional[Dict[str, object]] = None,
              drop: Optional[int] = None) -> Event:
        ev = Event(NAME, self._offset, bytes(self._held[:n]), error, fields)
        k = n if drop is None else drop
        del self._held[:k]
        self._offset += k
        return ev

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        self._held += data
        out: List[Event] = []
        while self._held:
            held = self._held
            if held[0] != binding.START:
                out.append(self._take(1, "garbage"))
                continue
            if len(held) < _HEADER:
                break
            n = held[2]
            if n > binding.MAX_DATA:
                out.append(self._take(_HEADER, "length", drop=1))
                continue
            if len(held) < n + _OVERHEAD:
                break
            check = binding.Decoder()
            frames = check.feed(bytes(held[:n + _OVERHEAD]))
            if check.rejected or len(frames) != 1:
                out.append(self._take(n + _OVERHEAD, "check", drop=1))
                continue
            node, payload = frames[0]
            out.append(self._take(n + _OVERHEAD, None, {
                "node": node & ~binding.REPLY & 0xFF, "reply": bool(node & binding.REPLY),
                "data": payload}))
        return out

    def finish(self) -> List[Event]:
        if not self._held:
            return []
        error = "truncated" if self._held[0] == binding.START else "garbage"
        return [self._take(len(self._held), error)]


def decoder(baud: int = 0) -> Decoder:
    """A toy decoder (the toy has no inter-byte gap: ``baud`` is unused)."""
    check_int(baud, "baud", 0, U32)
    return ToyDecoder()


def summary(event: Event) -> str:
    f = check_event(event, NAME).fields or {}
    return f"node {f['node']} {'reply' if f['reply'] else 'request'}"


def pair(event: Event, asked: object = None) -> Tuple[object, Optional[str], object]:
    """A reply carries its node with the REPLY bit: it answers the request to that node."""
    f = check_event(event, NAME).fields or {}
    return f["node"], "ans" if f["reply"] else "req", f["node"]
