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

from typing import Callable, Dict, List, Optional, Tuple

from .._native import ffi, lib
from ..errors import InvalidValueError
from ..g485 import codec as g485

PROTOCOLS = ("fap", "exec", "mikroc", "g485")

#: fields of each protocol's good frames, in output order (the JSON schema)
FIELDS: Dict[str, Tuple[str, ...]] = {
    "fap": ("msg", "msg_name", "dst", "src", "data"),
    "exec": ("node", "seq", "data"),
    "mikroc": ("address", "from_master", "data"),
    "g485": ("address", "rw", "pid", "data", "packet"),
}

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


class Decoder:
    """Base of the adapters: ``feed`` bytes, ``idle`` on a quiet line, ``finish`` at the end."""

    name = ""

    def feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        raise NotImplementedError

    def idle(self, now_ns: int) -> List[Event]:
        """The line has been quiet: apply the receiver's inter-byte gap, if it has one."""
        return []

    def idle_deadline(self) -> Optional[int]:
        """When :meth:`idle` would abandon a held partial frame (monotonic ns), or None."""
        return None

    def finish(self) -> List[Event]:
        """End of input: what is still held is a truncated frame or garbage."""
        return []


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
        self._d = ffi.new("lf_fap_decoder *")
        lib.lf_fap_decoder_init(self._d, gap_ns or lib.lf_fap_default_gap(baud))
        self._out: List[Event] = []
        self._handle = ffi.new_handle(self)
        lib.lf_fap_decoder_on_reject(self._d, lib.fap_py_mon_fap_reject, self._handle)

    def _frame(self, f: "ffi.CData") -> None:
        data = bytes(ffi.buffer(f.data, f.len)) if f.len else b""
        self._out.append(Event("fap", f.offset, bytes(ffi.buffer(f.raw, f.raw_len)), None, {
            "msg": f.msg, "msg_name": FAP_MSG_NAMES.get(f.msg, str(f.msg)),
            "dst": f.dst, "src": f.src, "data": data}))

    def _reject(self, reason: int, raw: "ffi.CData", n: int, offset: int) -> None:
        name = ffi.string(lib.lf_fap_reject_name(reason)).decode()
        self._out.append(Event("fap", offset, bytes(ffi.buffer(raw, n)),
                               name if reason != lib.LF_FAP_REJ_GARBAGE else "garbage"))

    def _take(self) -> List[Event]:
        out, self._out = self._out, []
        return out

    def feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        lib.lf_fap_decoder_feed(self._d, data, len(data), now_ns, lib.fap_py_mon_fap_frame,
                                self._handle)
        return self._take()

    def idle_deadline(self) -> Optional[int]:
        return lib.lf_fap_decoder_deadline(self._d) if self._d.n else None

    def idle(self, now_ns: int) -> List[Event]:
        lib.lf_fap_decoder_tick(self._d, now_ns, lib.fap_py_mon_fap_frame, self._handle)
        return self._take()

    def finish(self) -> List[Event]:
        if not self._d.n:
            return []
        far = lib.lf_fap_decoder_deadline(self._d)
        lib.lf_fap_decoder_tick(self._d, far, lib.fap_py_mon_fap_frame, self._handle)
        return [Event(e.protocol, e.offset, e.raw, "truncated") if e.error == "gap" else e
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
            out.append(Event(self.name, self._cursor, self._spans.get(self._cursor, upto), "garbage"))
        self._cursor = max(self._cursor, upto)

    def _held_from(self) -> int:
        """Stream offset where the partial frame the codec holds starts (else its position)."""
        raise NotImplementedError

    def idle(self, now_ns: int) -> List[Event]:
        """These receivers have no gap rule; a quiet line only shows the garbage so far."""
        out: List[Event] = []
        self._garbage_to(out, self._held_from())
        return out

    def _report(self, out: List[Event], start: int, end: int, error: Optional[str],
                fields: Optional[Dict[str, object]]) -> None:
        self._garbage_to(out, start)
        out.append(Event(self.name, start, self._spans.get(start, end), error, fields))
        self._cursor = end


class ExecDecoder(_SpanDecoder):
    """Exec async: execAsyncByteIn (csrc/execasync/codec.c) byte after byte, in C."""

    name = "exec"

    def __init__(self) -> None:
        super().__init__()
        self._s = ffi.new("lf_exec_scan *")
        lib.lf_exec_scan_init(self._s)

    def feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
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

    def feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
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
        self._p = g485.Parser()
        self._offset = 0          # stream offset of the parser's first held byte
        # the G485 simulator's default idle timeout
        self._gap = gap_ns or int(max(0.02, 50.0 / baud if baud else 0.02) * 1e9)
        self._last = 0
        self._spans = _Spans()

    def _expire(self, reason: str) -> List[Event]:
        """The parser drops a stale partial byte by byte; report the partial once, whole."""
        start, held = self._offset, self._p.buffered
        events = self._events(self._p.expire())
        if held:
            whole = Event("g485", start, self._spans.get(start, start + held), reason)
            events = [whole] + [e for e in events if not (e.offset == start and e.error == "gap")]
        return events

    def _events(self, evs: list) -> List[Event]:
        out: List[Event] = []
        for ev in evs:
            off = self._offset
            if isinstance(ev, g485.Packet):
                raw = ev.raw
                out.append(Event("g485", off, raw, None, {
                    "address": ev.address, "rw": raw[2] & 1, "pid": ev.pid,
                    "data": ev.data, "packet": ev.kind.value}))
                self._offset += len(raw)
                continue
            reason = _G485_REASONS[ev.issue]
            out.append(Event("g485", off, ev.data, reason))
            # a bad check resynchronises one byte after the candidate's start
            self._offset += 1 if ev.issue is g485.ParseIssue.BAD_CHECK else len(ev.data)
        return out

    def feed(self, data: bytes, now_ns: int = 0) -> List[Event]:
        self._last = now_ns
        self._spans.add(data)
        out = self._events(self._p.feed(data))
        self._spans.trim(self._offset)
        return out

    def idle_deadline(self) -> Optional[int]:
        return self._last + self._gap if self._p.buffered else None

    def idle(self, now_ns: int) -> List[Event]:
        if not self._p.buffered or now_ns < self._last + self._gap:
            return []
        return self._expire("gap")

    def finish(self) -> List[Event]:
        return self._expire("truncated")


def make_decoder(protocol: str, baud: int = 0) -> Decoder:
    """A fresh adapter for ``protocol`` (one of :data:`PROTOCOLS`)."""
    factories: Dict[str, Callable[[], Decoder]] = {
        "fap": lambda: FapDecoder(baud),
        "exec": ExecDecoder,
        "mikroc": MikrocDecoder,
        "g485": lambda: G485Decoder(baud),
    }
    if protocol not in factories:
        raise InvalidValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
    return factories[protocol]()


class EventFilter:
    """Drop bytes reported again after a bad frame covered them; merge garbage runs.

    A codec that rejects a candidate resumes at its second byte, so the
    rest of a bad frame comes back as garbage or as more rejected
    candidates; the monitor reports the bad frame once. Good frames are
    never dropped.
    """

    __slots__ = ("_covered", "_garbage")

    def __init__(self) -> None:
        self._covered = 0
        self._garbage: Optional[Event] = None

    def _flush(self, out: List[Event]) -> None:
        if self._garbage is not None:
            out.append(self._garbage)
            self._garbage = None

    def push(self, events: List[Event]) -> List[Event]:
        out: List[Event] = []
        for ev in events:
            if ev.error is None:
                self._flush(out)
                out.append(ev)
                self._covered = max(self._covered, ev.end)
                continue
            if ev.end <= self._covered:
                continue
            if ev.offset < self._covered:        # partly inside a reported bad frame
                cut = self._covered - ev.offset
                ev = Event(ev.protocol, self._covered, ev.raw[cut:], ev.error, None)
                if ev.error != "garbage":
                    ev.error = "garbage"
            if ev.error == "garbage":
                g = self._garbage
                if g is not None and g.end == ev.offset:
                    g.raw += ev.raw
                else:
                    self._flush(out)
                    self._garbage = ev
                continue
            self._flush(out)
            out.append(ev)
            self._covered = max(self._covered, ev.end)
        return out

    def finish(self) -> List[Event]:
        out: List[Event] = []
        self._flush(out)
        return out
