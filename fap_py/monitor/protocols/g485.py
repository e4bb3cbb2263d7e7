"""The monitor's G485 plug-in: fap_py.g485.codec.Parser, the simulator's and master's parser.

Frames are read through the codec's Packet (kind, address, pid, data), never by byte offset.
"""
from __future__ import annotations

from typing import List, Optional, Tuple, cast

from ..._validate import U32, check_int
from ...g485 import codec as g485
from ..decoders import NS_MAX, Decoder, Event, _ev, _text_field, check_event

NAME = "g485"
FIELDS = ("address", "rw", "pid", "data", "packet", "device")
#: the packet name of a wake-up preamble run (0xFF bytes before a request)
PREAMBLE = "Wake-up-Preamble"

__all__ = ["FIELDS", "NAME", "PREAMBLE", "G485Decoder", "decoder", "label", "pair", "summary"]

#: parser issues -> short reasons
_REASONS = {
    g485.ParseIssue.GARBAGE: "garbage",
    g485.ParseIssue.BAD_LENGTH: "length",
    g485.ParseIssue.BAD_CHECK: "check",
    g485.ParseIssue.UNKNOWN_PACKET: "packet",
    g485.ParseIssue.STALE: "gap",
}
#: packets whose address byte has the R/W bit clear (the master writes)
_WRITES = frozenset({g485.PacketKind.WRITE, g485.PacketKind.SET})
#: names of the packets that answer a request
_REPLIES = frozenset(k.value for k in g485.REPLY_KINDS)


class G485Decoder(Decoder):
    """G485's parser as a monitor decoder, with the simulator's inter-byte gap."""

    name = NAME

    def __init__(self, baud: int = 0, gap_ns: int = 0) -> None:
        check_int(baud, "baud", 0, U32)
        check_int(gap_ns, "gap_ns", 0, NS_MAX)
        self._p = g485.Parser()
        self._offset = 0          # stream offset of the parser's first held byte
        # the G485 simulator's default idle timeout
        self._gap = gap_ns or int(max(0.02, 50.0 / baud if baud else 0.02) * 1e9)
        self._last = 0
        self._buf = bytearray()   # the stream bytes from _base on (a held partial frame)
        self._base = 0
        self._held: Optional[Event] = None  # garbage ending in 0xFF: a wake-up preamble?
        self._asked: Optional[int] = None  # address of the last request (replies answer it)

    def _expire(self, reason: str) -> List[Event]:
        """The parser drops a stale partial byte by byte; report the partial once, whole."""
        start, held = self._offset, self._p.buffered
        events = self._events(self._p.expire())
        if held:
            raw = bytes(self._buf[start - self._base:start - self._base + held])
            whole = _ev(NAME, start, raw, reason)
            events = [whole] + [e for e in events if not (e.offset == start and e.error == "gap")]
        return events

    def _events(self, evs: list) -> List[Event]:
        out: List[Event] = []
        for ev in evs:
            off = self._offset
            if isinstance(ev, g485.Packet):
                out.append(_ev(NAME, off, ev.raw, None, {
                    "address": ev.address, "rw": 0 if ev.kind in _WRITES else 1, "pid": ev.pid,
                    "data": ev.data, "packet": ev.kind.value}))
                self._offset += len(ev.raw)
                continue
            out.append(_ev(NAME, off, ev.data, _REASONS[ev.issue]))
            # a bad check resynchronises one byte after the candidate's start
            self._offset += 1 if ev.issue is g485.ParseIssue.BAD_CHECK else len(ev.data)
        return out

    def _trim(self) -> None:
        k = self._offset - self._base
        if k > 4096:
            del self._buf[:k]
            self._base = self._offset

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        self._last = now_ns
        self._buf += data
        out = self._events(self._p.feed(data))
        self._trim()
        return out

    def idle_deadline(self) -> Optional[int]:
        return self._last + self._gap if self._p.buffered else None

    def _idle(self, now_ns: int) -> List[Event]:
        if not self._p.buffered or now_ns < self._last + self._gap:
            return []
        return self._expire("gap")

    def finish(self) -> List[Event]:
        return self._expire("truncated")

    def _refine(self, events: List[Event], final: bool = False) -> List[Event]:
        """Up to four 0xFF bytes of garbage just before a request are its wake-up
        preamble (master.py sends FF FF FF FF): one good record, not an error.
        Replies carry the master's address (127): ``device`` names the device
        asked by the last request."""
        out: List[Event] = []
        for ev in events:
            held, self._held = self._held, None
            if held is not None:
                if _request(ev) and held.end == ev.offset:
                    n = min(len(held.raw) - len(held.raw.rstrip(b"\xff")),
                            len(g485.WAKE_UP_PREAMBLE))
                    if n < len(held.raw):
                        out.append(_ev(NAME, held.offset, held.raw[:-n], "garbage"))
                    raw = held.raw[-n:]
                    out.append(_ev(NAME, held.end - n, raw, None, {
                        "address": None, "rw": None, "pid": None, "data": raw,
                        "packet": PREAMBLE, "device": None}))
                else:
                    out.append(held)
            if ev.error == "garbage" and ev.raw.endswith(b"\xff"):
                self._held = ev
                continue
            f = ev.fields
            if f is not None and ev.error is None:
                if f.get("packet") in _REPLIES:
                    f["device"] = self._asked
                elif _request(ev):
                    self._asked = cast(int, f.get("address"))
                    f["device"] = self._asked
            out.append(ev)
        if final and self._held is not None:
            out.append(self._held)
            self._held = None
        return out


def _request(ev: Event) -> bool:
    """A good frame a device is addressed by (not a reply, not a preamble)."""
    f = ev.fields
    return f is not None and ev.error is None and f.get("packet") not in _REPLIES and \
        f.get("packet") != PREAMBLE and isinstance(f.get("address"), int)


def decoder(baud: int = 0) -> Decoder:
    """G485's parser; ``baud`` (0 unknown) sets the inter-byte gap."""
    return G485Decoder(baud)


def summary(event: Event) -> str:
    f = check_event(event, NAME).fields or {}
    if f["packet"] == PREAMBLE:
        return f"{f['packet']} master"
    rw = "R" if f["rw"] else "W"
    if f["packet"] in _REPLIES:      # a reply: from the device the last request asked
        device = "?" if f.get("device") is None else f["device"]
        who = f"{device} -> master"
    else:
        who = f"master -> {f['address']}"
    return f"{f['packet']} {who} {rw} pid 0x{f['pid']:02x}"


def label(event: Event) -> Optional[str]:
    """The packet type (User-Register-Write, ...)."""
    return _text_field(event, NAME, "packet")


def pair(event: Event, asked: object = None) -> Tuple[object, Optional[str], object]:
    """A reply answers the last request (replies carry no device address: ``device``,
    set by the decoder, names it). A preamble is not a frame; a broadcast has no answer."""
    f = check_event(event, NAME).fields or {}
    if f.get("packet") == PREAMBLE:
        return None, None, None
    if f["packet"] in _REPLIES:
        device = f.get("device")
        return (f["address"] if device is None else device), "ans", None
    return f["address"], ("req" if f["address"] != g485.BROADCAST else None), None
