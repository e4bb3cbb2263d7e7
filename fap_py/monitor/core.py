"""The monitor pipeline: chunks of bytes in, timed records out.

A source hands :class:`Monitor` chunks (bytes, when the first one was on
the wire, how long a byte takes, which port sent them). The monitor feeds
one decoder (or, for ``auto``, every protocol's until one locks on), filters the
events and stamps each with the time and sender of its first byte.
"""
from __future__ import annotations

import bisect
import logging
import math
from typing import Any, Dict, List, Optional

from .. import _protocols
from .._validate import U32, check_bytes, check_int
from ..errors import InvalidTypeError, InvalidValueError
from .decoders import NS_MAX, Decoder, Event, EventFilter, make_decoder

log = logging.getLogger(__name__)

#: good frames one decoder needs, more than any other, for ``auto`` to lock on
AUTO_LOCK_FRAMES = 2
#: bytes after which ``auto`` picks the best decoder even without a clear lead
#: (if any found a frame; else it shows those bytes and goes on trying)
AUTO_GIVE_UP_BYTES = 4096
#: timeline segments (chunks) kept for events still to be placed
TIMELINE_KEEP = 16384
#: the largest wire time a record may carry, seconds (what a pcap record holds)
T_MAX = float(U32)


def _check_time(value: Any, what: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidTypeError(f"{what} must be a number of seconds, not {type(value).__name__}")
    try:
        v = float(value)
    except OverflowError:
        raise InvalidValueError(f"{what} must be in {lo}..{hi}, not {value}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise InvalidValueError(f"{what} must be a finite number in {lo}..{hi}, not {value}")
    return v


def _from_event(name: str) -> Any:
    """A read-only attribute of a Record that is its event's attribute ``name``."""
    return property(lambda self: getattr(self.event, name), doc=f"The event's ``{name}``.")


class Record:
    """A decoder event placed on the timeline."""

    __slots__ = ("event", "t", "t_end", "port")

    def __init__(self, event: Event, t: Optional[float], t_end: Optional[float],
                 port: Optional[int]) -> None:
        if not isinstance(event, Event):
            raise InvalidTypeError(f"event must be an Event, not {type(event).__name__}")
        for name, value in (("t", t), ("t_end", t_end)):
            if value is not None:
                _check_time(value, name, 0.0, 2.0 * T_MAX)
        if port is not None:
            check_int(port, "port", 0, 255)
        self.event = event
        self.t = t
        self.t_end = t_end
        self.port = port

    # what the decoder said, read through from the event (one rule: the event holds it)
    protocol: str = _from_event("protocol")
    ok: bool = _from_event("ok")
    error: Optional[str] = _from_event("error")
    raw: bytes = _from_event("raw")
    fields: Optional[Dict[str, object]] = _from_event("fields")


class _Timeline:
    """Time and sender of every stream offset: one segment per chunk. Private: only
    Monitor feeds it, with values it has checked."""

    __slots__ = ("_offsets", "_segs", "_pos", "_end")

    def __init__(self) -> None:
        self._offsets: List[int] = []
        self._segs: List[tuple] = []
        self._pos = 0
        self._end: Optional[float] = None   # wire end of the last timed chunk

    def add(self, n: int, t: Optional[float], char_s: float, port: Optional[int]) -> None:
        if t is None and port is None:
            self._pos += n
            return
        if t is not None:
            # a read's bytes are dated back from its arrival: never before the previous
            # chunk's end, so the times of the records never go backwards
            if self._end is not None and t < self._end:
                t = self._end
            self._end = t + n * char_s
        self._offsets.append(self._pos)
        self._segs.append((t, char_s, port))
        self._pos += n
        # an event is never more than auto's trial bytes plus a held bad-frame chain
        # behind (< 16 KiB): keep that many segments, even with one byte per chunk
        if len(self._offsets) > 2 * TIMELINE_KEEP:
            del self._offsets[:TIMELINE_KEEP]
            del self._segs[:TIMELINE_KEEP]

    def at(self, offset: int) -> tuple:
        """(wire start of the byte at offset or None, sender port or None)."""
        i = bisect.bisect_right(self._offsets, offset) - 1
        if i < 0:
            return None, None
        t, char_s, port = self._segs[i]
        if t is None:
            return None, port
        return t + (offset - self._offsets[i]) * char_s, port

    def end(self, offset: int) -> Optional[float]:
        """Wire end of the byte at offset (its start plus one character time), or None."""
        i = bisect.bisect_right(self._offsets, offset) - 1
        if i < 0:
            return None
        t, char_s, _port = self._segs[i]
        return None if t is None else t + (offset - self._offsets[i] + 1) * char_s


class Monitor:
    """Decode one stream with one protocol, or ``auto``: try every protocol's decoder."""

    def __init__(self, protocol: str = "auto", baud: int = 0) -> None:
        """``protocol``: "auto" or a protocol's name or alias (the protocol table,
        :mod:`fap_py._protocols`); ``baud``: the line rate (0 unknown).

        Raises InvalidTypeError / InvalidValueError for an unknown protocol or a
        baud outside 0..2**32-1.
        """
        if not isinstance(protocol, str):
            raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
        if protocol != "auto":
            try:
                protocol = _protocols.get(protocol).name
            except InvalidValueError:
                raise InvalidValueError(f"protocol must be auto or one of "
                                        f"{', '.join(_protocols.names())}, not {protocol!r}") from None
        self.protocol = protocol
        #: the decoders ``auto`` tries, in the table's order
        self.candidates = _protocols.names()
        self.baud = check_int(baud, "baud", 0, U32)
        #: good frames seen by the decoder ``auto`` locked on when it locked
        self.lock_frames = 0
        self.timeline = _Timeline()
        self.filter = EventFilter()
        self.bytes = 0
        self._window = 0          # auto: stream offset where the trials' current stretch began
        self.locked: Optional[str] = None if protocol == "auto" else protocol
        self.decoder: Optional[Decoder] = make_decoder(protocol, baud) if self.locked else None
        self._trials: Dict[str, Decoder] = {}
        self._trial_events: Dict[str, List[Event]] = {}
        if not self.locked:
            self._trials = {p: make_decoder(p, baud) for p in self.candidates}
            self._trial_events = {p: [] for p in self.candidates}

    # -- auto ----------------------------------------------------------
    def _score(self, p: str) -> int:
        return sum(1 for e in self._trial_events[p] if e.error is None)

    def _try_lock(self, at_end: bool) -> List[Event]:
        """Lock on a decoder with a clear lead (or the best one at the end, or after
        AUTO_GIVE_UP_BYTES with some frame). A stretch of AUTO_GIVE_UP_BYTES where
        no decoder found a frame is handed on as the first protocol's view of it
        (garbage, rejects) and the trials go on: noise before the traffic does not
        decide the protocol, and the trials' memory stays bounded."""
        scores = {p: self._score(p) for p in self.candidates}
        best = max(self.candidates, key=lambda p: scores[p])
        others = max((scores[p] for p in self.candidates if p != best), default=0)
        clear = scores[best] >= AUTO_LOCK_FRAMES and scores[best] > others
        window_full = self.bytes - self._window >= AUTO_GIVE_UP_BYTES
        if clear or at_end or (window_full and scores[best] > 0):
            self.locked = best
            self.decoder = self._trials[best]
            self.lock_frames = scores[best]
            log.info("auto: locked on %s (%d good frames; others at most %d)",
                     best, scores[best], others)
            events = self._trial_events[best]
            self._trials, self._trial_events = {}, {}
            return events
        if not window_full:
            return []
        self._window = self.bytes
        events = self._trial_events[self.candidates[0]]
        self._trial_events = {p: [] for p in self.candidates}
        return events

    def _decode(self, fn: str, *args: object, force: bool = False) -> List[Event]:
        if self.decoder is not None:
            return getattr(self.decoder, fn)(*args)
        for p, d in self._trials.items():
            self._trial_events[p].extend(getattr(d, fn)(*args))
        return self._try_lock(force)

    # -- input ---------------------------------------------------------
    def _refine(self, events: List[Event], final: bool = False) -> List[Event]:
        return self.decoder._refine(events, final) if self.decoder is not None else events

    def _records(self, events: List[Event]) -> List[Record]:
        return self._place(self._refine(self.filter.push(events)))

    def _flush(self) -> List[Record]:
        return self._place(self._refine(self.filter.finish(), True))

    def feed(self, data: bytes, t: Optional[float] = None, char_s: float = 0.0,
             port: Optional[int] = None, now_ns: int = 0) -> List[Record]:
        """Bytes whose first one was on the wire at ``t`` (seconds), ``char_s`` apart.

        ``data`` is any bytes-like object (bytes, bytearray, memoryview, also
        non-contiguous); ``t`` None or 0..2**32 s; ``char_s`` 0..1 s; ``port``
        None or 0..255; ``now_ns`` the CLOCK_MONOTONIC arrival (0 unknown).
        Bad values raise InvalidTypeError / InvalidValueError.
        """
        data = check_bytes(data, "data", 0, 2**62)
        if t is not None:
            t = _check_time(t, "t", 0.0, T_MAX)
        char_s = _check_time(char_s, "char_s", 0.0, 1.0)
        if port is not None:
            check_int(port, "port", 0, 255)
        check_int(now_ns, "now_ns", 0, NS_MAX)
        if not data:
            return []
        self.timeline.add(len(data), t, char_s, port)
        self.bytes += len(data)
        return self._records(self._decode("_feed", data, now_ns))

    def idle_deadline(self) -> Optional[int]:
        if self.decoder is not None:
            return self.decoder.idle_deadline()
        ds = [d for d in (t.idle_deadline() for t in self._trials.values()) if d is not None]
        return min(ds) if ds else None

    def idle(self, now_ns: int) -> List[Record]:
        """The line is quiet: apply the receiver's gap, and show a held garbage run now."""
        check_int(now_ns, "now_ns", 0, NS_MAX)
        recs = self._records(self._decode("_idle", now_ns))
        return recs + self._flush()

    def _place(self, events: List[Event]) -> List[Record]:
        tl = self.timeline
        out = []
        for ev in events:
            t, port = tl.at(ev.offset)
            out.append(Record(ev, t, tl.end(ev.end - 1) if t is not None else None, port))
        return out

    def finish(self) -> List[Record]:
        """End of input: flush the decoder (truncated frames, trailing garbage)."""
        events = self._decode("finish", force=True)
        return self._records(events) + self._flush()


__all__ = ["AUTO_GIVE_UP_BYTES", "AUTO_LOCK_FRAMES", "Monitor", "Record"]
