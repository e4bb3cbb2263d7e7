"""Protocol decoders turned into monitor events, and the protocols' plug-ins.

Every protocol the monitor knows has a plug-in, found by name through the
protocol table (:mod:`fap_py._protocols`): ``<package>.monitor.protocols.<name>``
holds its decoder, field list, summary text, request/reply pairing and pcap
label (docs/monitor.md, "Plug-ins"). This module holds what they share: the
:class:`Event` they report, the :class:`Decoder` interface, the one adapter
over the C codec table (:class:`CodecDecoder`, for every protocol whose
receiver decodes in C) and the :class:`EventFilter` that turns the events
into records tiling the stream. Nothing here knows a framing rule or a
protocol's name.

A codec that rejects a candidate frame resumes one byte later (FAP, G485),
so a bad frame's later bytes may be reported again; :class:`EventFilter`
drops those repeats and merges adjacent garbage runs.
"""
from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple, Union, cast, overload

from .. import _codec, _protocols
from .._validate import U32, check_bool, check_bytes, check_int
from ..errors import InvalidTypeError, InvalidValueError

#: the largest ``now_ns`` (CLOCK_MONOTONIC ns, a C int64)
NS_MAX = _codec.NS_MAX
#: the longest garbage record: a longer run of bytes outside any frame is
#: reported in records of this size as it comes (docs/monitor.md)
GARBAGE_MAX = 256
#: the longest run of overlapping rejected candidates held to see whether a
#: good frame starts inside (longer than any frame of the four protocols)
HOLD_MAX = 4096

#: the plug-in room of the monitor in the protocol table
TOOL = "monitor"

_plugins: Dict[_protocols.Protocol, Optional[ModuleType]] = {}


def _plugin_of(p: _protocols.Protocol) -> Optional[ModuleType]:
    if p not in _plugins:
        _plugins[p] = p.plugin(TOOL) if p.has_plugin(TOOL) else None
    return _plugins[p]


def monitor_protocols() -> Tuple[str, ...]:
    """The protocols the monitor decodes: every protocol of the table with a monitor
    plug-in, in table order (one added with ``_protocols.register`` included)."""
    return tuple(p.name for p in _protocols.all_protocols() if _plugin_of(p) is not None)


#: plug-ins by the name they were asked for (the hot path: a lookup per record)
_by_name: Dict[str, ModuleType] = {}


def plugin(protocol: str) -> ModuleType:
    """The monitor plug-in of ``protocol`` (its name or an alias);
    InvalidValueError when the table has no such protocol or it has no plug-in."""
    if not isinstance(protocol, str):
        raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
    mod = _by_name.get(protocol)
    if mod is not None:
        return mod
    try:
        p = _protocols.get(protocol)
    except _protocols.UnknownProtocolError:
        raise InvalidValueError(f"protocol must be one of {', '.join(monitor_protocols())}, "
                                f"not {protocol!r}") from None
    found = _plugin_of(p)
    if found is None:
        raise InvalidValueError(f"protocol {p.name!r} has no monitor plug-in")
    if p in _protocols.PROTOCOLS:       # built-in rows never leave the table
        _by_name[protocol] = found
    return found


class _LiveNames(Sequence):
    """:data:`PROTOCOLS`: a live, read-only view of :func:`monitor_protocols` (a
    protocol registered later is in it), usable where the tuple was."""

    def __len__(self) -> int:
        return len(monitor_protocols())

    @overload
    def __getitem__(self, i: int) -> str: ...

    @overload
    def __getitem__(self, i: slice) -> Tuple[str, ...]: ...

    def __getitem__(self, i: Union[int, slice]) -> Union[str, Tuple[str, ...]]:
        return monitor_protocols()[i]

    def __iter__(self) -> Iterator[str]:
        return iter(monitor_protocols())

    def __contains__(self, name: object) -> bool:
        return name in monitor_protocols()

    def __add__(self, other: Any) -> Tuple[str, ...]:
        return monitor_protocols() + tuple(other)

    def __radd__(self, other: Any) -> Tuple[str, ...]:
        return tuple(other) + monitor_protocols()

    def __repr__(self) -> str:
        return repr(monitor_protocols())


#: the protocols the monitor decodes (a live view of :func:`monitor_protocols`; typed as
#: the tuple it stands in for: indexing, ``in``, iteration and ``+`` with a tuple work)
PROTOCOLS: Tuple[str, ...] = cast(Tuple[str, ...], _LiveNames())


def dissector(protocol: str) -> str:
    """The Wireshark dissector name (filter prefix) of ``protocol``'s fields."""
    mod = plugin(protocol)
    return str(getattr(mod, "DISSECTOR", _protocols.get(protocol).name))


def fields() -> Dict[str, Tuple[str, ...]]:
    """Each protocol's good-frame fields in output order (the JSON schema), from its plug-in."""
    return {name: tuple(plugin(name).FIELDS) for name in monitor_protocols()}


class Event:
    """One thing the decoder reported: a frame (ok), a bad frame or garbage.

    ``offset`` is the stream offset of ``raw[0]``; ``fields`` the protocol
    fields of a good frame (None for errors).
    """

    __slots__ = ("protocol", "offset", "raw", "error", "fields")

    def __init__(self, protocol: str, offset: int, raw: bytes, error: Optional[str],
                 fields: Optional[Dict[str, object]] = None) -> None:
        """Checked: InvalidTypeError / InvalidValueError for a bad argument."""
        if protocol not in monitor_protocols():
            if not isinstance(protocol, str):
                raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
            raise InvalidValueError(f"protocol must be one of {', '.join(monitor_protocols())}, "
                                    f"not {protocol!r}")
        check_int(offset, "offset", 0, 2**64 - 1)
        raw = check_bytes(raw, "raw", 0, 2**62)
        if error is not None and not isinstance(error, str):
            raise InvalidTypeError(f"error must be None or a str, not {type(error).__name__}")
        if fields is not None and not isinstance(fields, dict):
            raise InvalidTypeError(f"fields must be None or a dict, not {type(fields).__name__}")
        self.protocol = protocol
        self.offset = offset
        self.raw = raw
        self.error = error
        self.fields = fields

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def end(self) -> int:
        return self.offset + len(self.raw)

    def __repr__(self) -> str:
        return f"<Event {self.protocol} @{self.offset} {self.error or 'ok'} {self.raw.hex()}>"


def _ev(protocol: str, offset: int, raw: bytes, error: Optional[str],
        fields: Optional[Dict[str, object]] = None) -> Event:
    """An Event from the adapters' own values (unchecked: the hot path)."""
    ev = Event.__new__(Event)
    ev.protocol, ev.offset, ev.raw, ev.error, ev.fields = protocol, offset, raw, error, fields
    return ev


def check_event(event: Any, protocol: str) -> Event:
    """``event`` if it is an :class:`Event` of ``protocol``; else InvalidTypeError /
    InvalidValueError. For the plug-ins' public functions."""
    if not isinstance(protocol, str):
        raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
    if not isinstance(event, Event):
        raise InvalidTypeError(f"event must be an Event, not {type(event).__name__}")
    if event.protocol != protocol:
        raise InvalidValueError(f"event must be a {protocol} event, not {event.protocol}")
    return event


def _text_field(event: Any, protocol: str, key: str) -> Optional[str]:
    """Field ``key`` of a ``protocol`` event if it is a str, else None (a plug-in's
    ``label``: the message or packet type)."""
    text = (check_event(event, protocol).fields or {}).get(key)
    return text if isinstance(text, str) else None


class Decoder:
    """The interface of the plug-ins' decoders: ``feed`` bytes, ``idle`` on a quiet
    line, ``finish`` at the end. ``name`` is the protocol's one name."""

    name = ""

    def feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        """Decode bytes (any bytes-like object) that arrived at ``now_ns``
        (CLOCK_MONOTONIC ns, 0 unknown); InvalidTypeError / InvalidValueError
        for anything else."""
        data = check_bytes(data, "data", 0, 2**62)
        return self._feed(data, check_int(now_ns, "now_ns", 0, NS_MAX))

    def idle(self, now_ns: int) -> List[Event]:
        """The line has been quiet: apply the receiver's inter-byte gap, if it has one."""
        return self._idle(check_int(now_ns, "now_ns", 0, NS_MAX))

    def _feed(self, data: bytes, now_ns: int) -> List[Event]:
        raise NotImplementedError

    def _idle(self, now_ns: int) -> List[Event]:
        return []

    def idle_deadline(self) -> Optional[int]:
        """When :meth:`idle` would abandon a held partial frame (monotonic ns), or None."""
        return None

    def finish(self) -> List[Event]:
        """End of input: what is still held is a truncated frame or garbage."""
        return []

    def refine(self, events: List[Event], final: bool = False) -> List[Event]:
        """The filtered records in order, for a protocol's last look (G485: the
        wake-up preamble, the device a reply answers). ``final``: hand on all."""
        return self._refine(_check_events(events), check_bool(final, "final"))

    def _refine(self, events: List[Event], final: bool) -> List[Event]:
        return events


#: a plug-in's conversion of a C codec frame into its monitor fields:
#: (header field values in the C row's order, data, message type name or None) -> fields
FieldsOf = Callable[[Tuple[int, ...], bytes, Optional[str]], Dict[str, object]]


class CodecDecoder(Decoder):
    """The monitor's one adapter over the C codec table (:mod:`fap_py._codec`):
    the protocol's receiver decoder from C, its frames and rejects as events.

    ``fields`` turns a codec frame into the plug-in's fields (default: the C
    row's header fields by name, and ``data``)."""

    def __init__(self, protocol: str, baud: int = 0, gap_ns: int = 0,
                 fields: Optional[FieldsOf] = None) -> None:
        if not isinstance(protocol, str):
            raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
        check_int(baud, "baud", 0, U32)
        check_int(gap_ns, "gap_ns", 0, NS_MAX)
        if fields is not None and not callable(fields):
            raise InvalidTypeError(f"fields must be None or callable, not {type(fields).__name__}")
        plugin(protocol)                       # a protocol the monitor decodes
        name = self.name = _protocols.get(protocol).name
        codec = _codec.find(name)
        names = codec.fields
        conv: FieldsOf = fields or (lambda values, data, _n: dict(zip(names, values), data=data))
        self._d = codec.decoder(
            baud, gap_ns,
            frame=lambda off, raw, data, values, fname: _ev(name, off, raw, None,
                                                            conv(values, data, fname)),
            reject=lambda off, raw, _code, reason: _ev(name, off, raw, reason))

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        return self._d.feed(data, now_ns)

    def idle_deadline(self) -> Optional[int]:
        return self._d.deadline()

    def _idle(self, now_ns: int) -> List[Event]:
        return self._d.tick(now_ns)

    def finish(self) -> List[Event]:
        return self._d.finish()


def _check_events(events: object) -> List[Event]:
    if not isinstance(events, list) or not all(isinstance(e, Event) for e in events):
        raise InvalidTypeError(f"events must be a list of Event, not {type(events).__name__}")
    return events


def make_decoder(protocol: str, baud: int = 0) -> Decoder:
    """A fresh decoder for ``protocol`` (a name or alias of :data:`PROTOCOLS`), from its plug-in."""
    mod = plugin(protocol)
    check_int(baud, "baud", 0, U32)
    dec: Decoder = mod.decoder(baud)
    return dec


def __getattr__(name: str) -> Any:
    """``FIELDS`` is :func:`fields` (a live view of the plug-ins' fields)."""
    if name == "FIELDS":
        return fields()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


class EventFilter:
    """Order the decoder's events into records that tile the stream once.

    A codec that rejects a candidate resumes at its second byte, so the
    rest of a bad frame comes back as garbage or as more rejected
    candidates; the monitor reports the bad frame once. A bad frame is held
    until the decoder has moved past it: a good frame found inside it wins,
    and the candidate's bytes before that frame become garbage, so records
    never overlap (unless more than :data:`HOLD_MAX` bytes of overlapping
    bad candidates chain up, which only a crafted stream does). Good frames
    are never dropped. Adjacent garbage is merged into records of at most
    :data:`GARBAGE_MAX` bytes, handed on as soon as one is full: an
    unframed stream is reported as it comes, never held.
    """

    __slots__ = ("_covered", "_pending", "_garbage", "_g_proto", "_g_off")

    def __init__(self) -> None:
        self._covered = 0                  # stream offset up to which bytes are reported or held
        self._pending: List[Event] = []    # a bad frame (and what follows it) until resolved
        self._garbage = bytearray()        # the garbage run held (< GARBAGE_MAX bytes)
        self._g_proto = ""
        self._g_off = 0                    # stream offset of the held run's first byte

    def _flush_garbage(self, out: List[Event]) -> None:
        if self._garbage:
            out.append(_ev(self._g_proto, self._g_off, bytes(self._garbage), "garbage"))
            self._garbage = bytearray()

    def _emit(self, out: List[Event], ev: Event) -> None:
        if ev.error != "garbage":
            self._flush_garbage(out)
            out.append(ev)
            return
        if self._garbage and self._g_off + len(self._garbage) != ev.offset:
            self._flush_garbage(out)
        raw, pos = ev.raw, 0
        while pos < len(raw):
            if not self._garbage:
                self._g_proto, self._g_off = ev.protocol, ev.offset + pos
            take = min(len(raw) - pos, GARBAGE_MAX - len(self._garbage))
            self._garbage += raw[pos:pos + take]
            pos += take
            if len(self._garbage) >= GARBAGE_MAX:
                self._flush_garbage(out)

    def _flush_pending(self, out: List[Event]) -> None:
        for ev in self._pending:
            self._emit(out, ev)
        self._pending = []

    def _cut_pending(self, at: int) -> None:
        """A good frame starts at ``at``: held bytes from there on are its."""
        kept: List[Event] = []
        for ev in self._pending:
            if ev.offset >= at:
                break
            if ev.end > at:
                ev = _ev(ev.protocol, ev.offset, ev.raw[:at - ev.offset], "garbage")
            kept.append(ev)
        self._pending = kept

    def push(self, events: List[Event]) -> List[Event]:
        out: List[Event] = []
        for ev in _check_events(events):
            if ev.error is None:
                inside = bool(self._pending) and ev.offset < self._covered
                if inside:
                    self._cut_pending(ev.offset)
                self._flush_pending(out)
                self._emit(out, ev)
                # after a frame found inside held bytes the decoder goes on from its end
                self._covered = ev.end if inside else max(self._covered, ev.end)
                continue
            if ev.end <= self._covered:          # scanned again inside a bad frame
                continue
            if len(ev.raw) == 1:                 # a byte that starts no frame
                ev = _ev(ev.protocol, ev.offset, ev.raw, "garbage")
            straddles = ev.offset < self._covered
            if straddles:                        # partly inside: its new bytes are garbage
                cut = self._covered - ev.offset
                ev = _ev(ev.protocol, self._covered, ev.raw[cut:], "garbage")
            elif self._pending:                  # the decoder has passed the held frame
                self._flush_pending(out)
            if self._pending or ev.error != "garbage":
                self._pending.append(ev)
            else:
                self._emit(out, ev)
            self._covered = ev.end
            if self._pending and self._covered - self._pending[0].offset > HOLD_MAX:
                self._flush_pending(out)
        return out

    def finish(self) -> List[Event]:
        """Hand on everything held (end of input, or a quiet line)."""
        out: List[Event] = []
        self._flush_pending(out)
        self._flush_garbage(out)
        return out


__all__ = ["GARBAGE_MAX", "HOLD_MAX", "NS_MAX", "PROTOCOLS", "CodecDecoder", "Decoder", "Event",
           "EventFilter", "check_event", "dissector", "fields", "make_decoder", "monitor_protocols", "plugin"]
