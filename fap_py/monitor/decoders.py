"""Protocol adapters: the receivers' own decoders turned into monitor events.

Every adapter feeds bytes to the codec the protocol's receiver uses (the C
decoders through cffi for FAP, exec async and mikroC; the Python G485
parser) and turns what it reports into :class:`Event` objects: a good frame
with its fields, a bad frame with the codec's reason, or garbage. Nothing
here knows a framing rule; the adapters only keep stream offsets so every
event carries its raw bytes and where they lie in the stream.

A codec that rejects a candidate frame resumes one byte later (FAP, G485),
so a bad frame's later bytes may be reported again; :class:`EventFilter`
drops those repeats and merges adjacent garbage runs.
"""
from __future__ import annotations

from typing import Callable, Dict, List, Optional, Tuple, cast

from .._native import ffi, lib
from .._validate import U32, check_bool, check_bytes, check_int
from ..errors import InvalidTypeError, InvalidValueError
from ..g485 import codec as g485

PROTOCOLS = ("fap", "exec", "mikroc", "g485")

#: the largest ``now_ns`` (CLOCK_MONOTONIC ns, a C int64)
NS_MAX = 2**63 - 1
#: the longest garbage record: a longer run of bytes outside any frame is
#: reported in records of this size as it comes (docs/monitor.md)
GARBAGE_MAX = 256
#: the longest run of overlapping rejected candidates held to see whether a
#: good frame starts inside (longer than any frame of the four protocols)
HOLD_MAX = 4096

#: fields of each protocol's good frames, in output order (the JSON schema)
FIELDS: Dict[str, Tuple[str, ...]] = {
    "fap": ("msg", "msg_name", "dst", "src", "data"),
    "exec": ("node", "seq", "data"),
    "mikroc": ("address", "from_master", "data"),
    "g485": ("address", "rw", "pid", "data", "packet", "device"),
}

#: the G485 packet name of a wake-up preamble run (0xFF bytes before a request)
G485_PREAMBLE = "Wake-up-Preamble"

#: FAP message names, from the C enum (LF_FAP_SEND_DATA -> "SEND_DATA")
FAP_MSG_NAMES: Dict[int, str] = {
    v: k[len("LF_FAP_"):] for v, k in ffi.typeof("enum lf_fap_msg").elements.items()}


class Event:
    """One thing the decoder reported: a frame (ok), a bad frame or garbage.

    ``offset`` is the stream offset of ``raw[0]``; ``fields`` the protocol
    fields of a good frame (None for errors).
    """

    __slots__ = ("protocol", "offset", "raw", "error", "fields")

    def __init__(self, protocol: str, offset: int, raw: bytes, error: Optional[str],
                 fields: Optional[Dict[str, object]] = None) -> None:
        """Checked: InvalidTypeError / InvalidValueError for a bad argument."""
        if protocol not in PROTOCOLS:
            raise InvalidValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, "
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


class Decoder:
    """Base of the adapters: ``feed`` bytes, ``idle`` on a quiet line, ``finish`` at the end."""

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


class _Spans:
    """A window on the stream bytes so spans reported as offsets can be sliced."""

    __slots__ = ("buf", "base")

    def __init__(self) -> None:
        self.buf = bytearray()
        self.base = 0

    def add(self, data: bytes) -> None:
        self.buf += data

    def get(self, start: int, end: int) -> bytes:
        return bytes(self.buf[start - self.base:end - self.base])

    def trim(self, keep_from: int) -> None:
        k = keep_from - self.base
        if k > 4096:
            del self.buf[:k]
            self.base = keep_from


class FapDecoder(Decoder):
    """FAP: csrc/fap/fap_frame.c's stream decoder (as the engine feeds it)."""

    name = "fap"

    def __init__(self, baud: int = 0, gap_ns: int = 0) -> None:
        check_int(baud, "baud", 0, U32)
        check_int(gap_ns, "gap_ns", 0, NS_MAX)
        self._d = ffi.new("lf_fap_decoder *")
        lib.lf_fap_decoder_init(self._d, gap_ns or lib.lf_fap_default_gap(baud))
        self._out: List[Event] = []
        self._handle = ffi.new_handle(self)
        lib.lf_fap_decoder_on_reject(self._d, lib.fap_py_mon_fap_reject, self._handle)

    def _frame(self, f: "ffi.CData") -> None:
        data = bytes(ffi.buffer(f.data, f.len)) if f.len else b""
        self._out.append(_ev("fap", f.offset, bytes(ffi.buffer(f.raw, f.raw_len)), None, {
            "msg": f.msg, "msg_name": FAP_MSG_NAMES.get(f.msg, str(f.msg)),
            "dst": f.dst, "src": f.src, "data": data}))

    def _reject(self, reason: int, raw: "ffi.CData", n: int, offset: int) -> None:
        name = ffi.string(lib.lf_fap_reject_name(reason)).decode()
        self._out.append(_ev("fap", offset, bytes(ffi.buffer(raw, n)),
                               name if reason != lib.LF_FAP_REJ_GARBAGE else "garbage"))

    def _take(self) -> List[Event]:
        out, self._out = self._out, []
        return out

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        lib.lf_fap_decoder_feed(self._d, data, len(data), now_ns, lib.fap_py_mon_fap_frame,
                                self._handle)
        return self._take()

    def idle_deadline(self) -> Optional[int]:
        return lib.lf_fap_decoder_deadline(self._d) if self._d.n else None

    def _idle(self, now_ns: int) -> List[Event]:
        lib.lf_fap_decoder_tick(self._d, now_ns, lib.fap_py_mon_fap_frame, self._handle)
        return self._take()

    def finish(self) -> List[Event]:
        if not self._d.n:
            return []
        far = lib.lf_fap_decoder_deadline(self._d)
        lib.lf_fap_decoder_tick(self._d, far, lib.fap_py_mon_fap_frame, self._handle)
        return [_ev(e.protocol, e.offset, e.raw, "truncated") if e.error == "gap" else e
                for e in self._take()]


@ffi.def_extern()
def fap_py_mon_fap_frame(ctx: "ffi.CData", f: "ffi.CData", now: int) -> None:
    ffi.from_handle(ctx)._frame(f)


@ffi.def_extern()
def fap_py_mon_fap_reject(ctx: "ffi.CData", reason: int, raw: "ffi.CData", n: int,
                          offset: int, now: int) -> None:
    ffi.from_handle(ctx)._reject(reason, raw, n, offset)


class _SpanDecoder(Decoder):
    """Adapters over a C scan helper that reports spans [rep_start, rep_end)."""

    def __init__(self) -> None:
        self._spans = _Spans()
        self._cursor = 0          # stream offset up to which everything was reported

    def _garbage_to(self, out: List[Event], upto: int) -> None:
        if upto > self._cursor:
            out.append(_ev(self.name, self._cursor, self._spans.get(self._cursor, upto), "garbage"))
        self._cursor = max(self._cursor, upto)

    def _held_from(self) -> int:
        """Stream offset where the partial frame the codec holds starts (else its position)."""
        raise NotImplementedError

    def _early_garbage(self, out: List[Event]) -> None:
        """A long run outside any frame is reported now, not held: all of it but the
        last byte (with the next one it may start a frame: exec's DLE STX)."""
        upto = self._held_from() - 1
        if upto - self._cursor >= GARBAGE_MAX:
            self._garbage_to(out, upto)

    def _idle(self, now_ns: int) -> List[Event]:
        """These receivers have no gap rule; a quiet line only shows the garbage so far."""
        out: List[Event] = []
        self._garbage_to(out, self._held_from())
        return out

    def _report(self, out: List[Event], start: int, end: int, error: Optional[str],
                fields: Optional[Dict[str, object]]) -> None:
        self._garbage_to(out, start)
        out.append(_ev(self.name, start, self._spans.get(start, end), error, fields))
        self._cursor = end


class ExecDecoder(_SpanDecoder):
    """Exec async: execAsyncByteIn (csrc/execasync/codec.c) byte after byte, in C."""

    name = "exec"

    def __init__(self) -> None:
        super().__init__()
        self._s = ffi.new("lf_exec_scan *")
        lib.lf_exec_scan_init(self._s)

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        s = self._s
        self._spans.add(data)
        out: List[Event] = []
        pos, n = 0, len(data)
        src = ffi.from_buffer(data)
        while pos < n:
            pos += lib.lf_exec_scan_feed(s, src + pos, n - pos)
            st = s.st
            if st.Status == lib.EXEC_ASYNC_NONE:
                break
            if st.Status == lib.EXEC_ASYNC_GOOD:
                self._report(out, s.rep_start, s.rep_end, None, {
                    "node": st.Node, "seq": st.SeqNo,
                    "data": bytes(ffi.buffer(s.buf, st.Length))})
            else:
                reason = ffi.string(lib.lf_exec_status_reason(st.Status)).decode()
                self._report(out, s.rep_start, s.rep_end, reason, None)
        self._early_garbage(out)
        self._trim()
        return out

    def _held_from(self) -> int:
        s = self._s
        return s.start if lib.lf_exec_rx_in_frame(ffi.addressof(s, "st")) else s.pos

    def _trim(self) -> None:
        keep = self._cursor
        if lib.lf_exec_rx_in_frame(ffi.addressof(self._s, "st")):
            keep = min(keep, self._s.start)
        self._spans.trim(keep)

    def finish(self) -> List[Event]:
        out: List[Event] = []
        s = self._s
        if lib.lf_exec_rx_in_frame(ffi.addressof(s, "st")) and s.start >= self._cursor:
            self._report(out, s.start, s.pos, "truncated", None)
        self._garbage_to(out, s.pos)
        return out


class MikrocDecoder(_SpanDecoder):
    """mikroC RS-485: mikrocRS485_DecoderFeed (csrc/mikroc/mikroc_codec.c), in C."""

    name = "mikroc"

    def __init__(self) -> None:
        super().__init__()
        self._s = ffi.new("lf_mikroc_scan *")
        lib.lf_mikroc_scan_init(self._s)
        self._master_flag = lib.MIKROC_RS485_DL_MASTER

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        s = self._s
        self._spans.add(data)
        out: List[Event] = []
        pos, n = 0, len(data)
        src = ffi.from_buffer(data)
        frame_code = lib.MIKROC_RS485_FRAME
        while pos < n:
            pos += lib.lf_mikroc_scan_feed(s, src + pos, n - pos)
            code = s.code
            if code == 0:
                break
            s.code = 0
            if code == frame_code:
                f = s.f
                self._report(out, s.rep_start, s.rep_end, None, {
                    "address": f.address, "from_master": bool(f.datalen & self._master_flag),
                    "data": bytes(f.data[0:f.count])})
            else:
                self._report(out, s.rep_start, s.rep_end, ffi.string(s.reason).decode(), None)
        self._early_garbage(out)
        keep = self._cursor
        if lib.lf_mikroc_scan_in_frame(s):
            keep = min(keep, s.start)
        self._spans.trim(keep)
        return out

    def _held_from(self) -> int:
        s = self._s
        return s.start if lib.lf_mikroc_scan_in_frame(s) else s.pos

    def finish(self) -> List[Event]:
        out: List[Event] = []
        s = self._s
        if lib.lf_mikroc_scan_in_frame(s) and s.start >= self._cursor:
            self._report(out, s.start, s.pos, "truncated", None)
        self._garbage_to(out, s.pos)
        return out


#: G485 parser issues -> short reasons
_G485_REASONS = {
    g485.ParseIssue.GARBAGE: "garbage",
    g485.ParseIssue.BAD_LENGTH: "length",
    g485.ParseIssue.BAD_CHECK: "check",
    g485.ParseIssue.UNKNOWN_PACKET: "packet",
    g485.ParseIssue.STALE: "gap",
}


class G485Decoder(Decoder):
    """G485: fap_py.g485.codec.Parser, the simulator's and master's parser."""

    name = "g485"

    def __init__(self, baud: int = 0, gap_ns: int = 0) -> None:
        check_int(baud, "baud", 0, U32)
        check_int(gap_ns, "gap_ns", 0, NS_MAX)
        self._p = g485.Parser()
        self._offset = 0          # stream offset of the parser's first held byte
        # the G485 simulator's default idle timeout
        self._gap = gap_ns or int(max(0.02, 50.0 / baud if baud else 0.02) * 1e9)
        self._last = 0
        self._spans = _Spans()
        self._held: Optional[Event] = None  # garbage ending in 0xFF: a wake-up preamble?
        self._asked: Optional[int] = None  # address of the last request (replies answer it)

    def _expire(self, reason: str) -> List[Event]:
        """The parser drops a stale partial byte by byte; report the partial once, whole."""
        start, held = self._offset, self._p.buffered
        events = self._events(self._p.expire())
        if held:
            whole = _ev("g485", start, self._spans.get(start, start + held), reason)
            events = [whole] + [e for e in events if not (e.offset == start and e.error == "gap")]
        return events

    def _events(self, evs: list) -> List[Event]:
        out: List[Event] = []
        for ev in evs:
            off = self._offset
            if isinstance(ev, g485.Packet):
                raw = ev.raw
                out.append(_ev("g485", off, raw, None, {
                    "address": ev.address, "rw": raw[2] & 1, "pid": ev.pid,
                    "data": ev.data, "packet": ev.kind.value}))
                self._offset += len(raw)
                continue
            reason = _G485_REASONS[ev.issue]
            out.append(_ev("g485", off, ev.data, reason))
            # a bad check resynchronises one byte after the candidate's start
            self._offset += 1 if ev.issue is g485.ParseIssue.BAD_CHECK else len(ev.data)
        return out

    def _feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        self._last = now_ns
        self._spans.add(data)
        out = self._events(self._p.feed(data))
        self._spans.trim(self._offset)
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
                if _g485_request(ev) and held.end == ev.offset:
                    n = min(len(held.raw) - len(held.raw.rstrip(b"\xff")),
                            len(g485.WAKE_UP_PREAMBLE))
                    if n < len(held.raw):
                        out.append(_ev("g485", held.offset, held.raw[:-n], "garbage"))
                    raw = held.raw[-n:]
                    out.append(_ev("g485", held.end - n, raw, None, {
                        "address": None, "rw": None, "pid": None, "data": raw,
                        "packet": G485_PREAMBLE, "device": None}))
                else:
                    out.append(held)
            if ev.error == "garbage" and ev.raw.endswith(b"\xff"):
                self._held = ev
                continue
            f = ev.fields
            if f is not None and len(ev.raw) > 2:
                if ev.raw[2] == g485.SMA_R:
                    f["device"] = self._asked
                elif _g485_request(ev):
                    self._asked = cast(int, f.get("address"))
                    f["device"] = self._asked
            out.append(ev)
        if final and self._held is not None:
            out.append(self._held)
            self._held = None
        return out


def _g485_request(ev: Event) -> bool:
    """A good G485 frame a device is addressed by (not a reply, not a preamble)."""
    f = ev.fields
    return f is not None and ev.error is None and len(ev.raw) > 2 and \
        ev.raw[2] != g485.SMA_R and isinstance(f.get("address"), int)


def _check_events(events: object) -> List[Event]:
    if not isinstance(events, list) or not all(isinstance(e, Event) for e in events):
        raise InvalidTypeError(f"events must be a list of Event, not {type(events).__name__}")
    return events


def make_decoder(protocol: str, baud: int = 0) -> Decoder:
    """A fresh adapter for ``protocol`` (one of :data:`PROTOCOLS`)."""
    factories: Dict[str, Callable[[], Decoder]] = {
        "fap": lambda: FapDecoder(baud),
        "exec": ExecDecoder,
        "mikroc": MikrocDecoder,
        "g485": lambda: G485Decoder(baud),
    }
    if not isinstance(protocol, str):
        raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
    if protocol not in factories:
        raise InvalidValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
    check_int(baud, "baud", 0, U32)
    return factories[protocol]()


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


__all__ = ["FIELDS", "G485_PREAMBLE", "GARBAGE_MAX", "HOLD_MAX", "PROTOCOLS", "Event",
           "ExecDecoder", "FapDecoder", "G485Decoder", "MikrocDecoder", "make_decoder"]
