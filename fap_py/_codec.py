"""The C codec table (``include/fap_codec.h``) for Python: one adapter over every row.

Each row is a protocol's receiver decoder from C (FAP, exec async, mikroC), the one its
engine uses. :func:`find` gives a :class:`Codec`; its :meth:`Codec.decoder` is sans-I/O:
feed bytes and the time they arrived, get back :class:`Frame` and :class:`Reject` records
in stream order, each with its stream offset and raw bytes::

    dec = find("exec").decoder()
    for item in dec.feed(data, now_ns) + dec.finish():
        ...

Private: the monitor reaches the table only through this module (docs/c-api.md,
"Codec table"; docs/architecture.md).
"""
from __future__ import annotations

from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

from ._native import ffi, lib
from ._validate import U32, check_bytes, check_int
from .errors import InvalidTypeError, InvalidValueError

__all__ = ["Codec", "Decoder", "Frame", "Reject", "find", "names", "NS_MAX"]

#: the largest ``now_ns`` / ``gap_ns`` (CLOCK_MONOTONIC ns, a C int64)
NS_MAX = 2**63 - 1


class Frame:
    """A good frame: ``fields`` by the row's field names, ``name`` its message type (or None)."""

    __slots__ = ("offset", "raw", "data", "fields", "name")

    def __init__(self, offset: int, raw: bytes, data: bytes, fields: Dict[str, int],
                 name: Optional[str]) -> None:
        self.offset, self.raw, self.data, self.fields, self.name = offset, raw, data, fields, name

    def __repr__(self) -> str:
        return f"<Frame @{self.offset} {self.fields} {self.data.hex()}>"


class Reject:
    """Dropped bytes: ``reason`` is the row's name of ``code`` ("garbage", "crc", ...)."""

    __slots__ = ("offset", "raw", "code", "reason")

    def __init__(self, offset: int, raw: bytes, code: int, reason: str) -> None:
        self.offset, self.raw, self.code, self.reason = offset, raw, code, reason

    def __repr__(self) -> str:
        return f"<Reject @{self.offset} {self.reason} {self.raw.hex()}>"


Item = Union[Frame, Reject]
#: builds what a decoder returns for a good frame: (offset, raw, data, header field values
#: in the row's order, message type name or None)
FrameBuilder = Callable[[int, bytes, bytes, Tuple[int, ...], Optional[str]], Any]
#: builds what a decoder returns for dropped bytes: (offset, raw, code, reason)
RejectBuilder = Callable[[int, bytes, int, str], Any]


class Codec:
    """One row of the table (see :func:`find`)."""

    __slots__ = ("_c", "name", "fields", "max_frame", "_reasons")

    def __init__(self, row: "ffi.CData") -> None:
        self._c = row
        self.name: str = ffi.string(row.name).decode()
        #: the names of a frame's header fields, in the row's order
        self.fields: Tuple[str, ...] = tuple(
            ffi.string(row.field_names[i]).decode() for i in range(row.n_fields))
        self.max_frame: int = row.max_frame
        self._reasons: Dict[int, str] = {}

    def reject_name(self, code: int) -> str:
        """The row's short name of a reject code ("?" for an unknown one)."""
        check_int(code, "code", -2**31, 2**31 - 1)
        name = self._reasons.get(code)
        if name is None:
            name = self._reasons[code] = ffi.string(self._c.reject_name(code)).decode()
        return name

    def decoder(self, baud: int = 0, gap_ns: int = 0, frame: Optional[FrameBuilder] = None,
                reject: Optional[RejectBuilder] = None) -> "Decoder":
        """A fresh decoder; ``baud`` (0 unknown) and ``gap_ns`` (0: from the baud) set
        the inter-byte gap where the receiver has one. ``frame`` / ``reject`` build what it
        returns (default :class:`Frame` / :class:`Reject`)."""
        return Decoder(self, baud, gap_ns, frame, reject)

    def encode(self, fields: Sequence[int], data: bytes = b"") -> bytes:
        """One frame with header ``fields`` (in :attr:`fields` order) and ``data``;
        InvalidValueError when the row's encoder refuses them."""
        if isinstance(fields, (str, bytes)) or not isinstance(fields, (tuple, list)):
            raise InvalidTypeError(f"fields must be a tuple of ints, not {type(fields).__name__}")
        if len(fields) != len(self.fields):
            raise InvalidValueError(f"{self.name}: fields must be {len(self.fields)} ints "
                                    f"({', '.join(self.fields)}), not {len(fields)}")
        values = [check_int(v, name, 0, U32) for v, name in zip(fields, self.fields)]
        data = check_bytes(data, "data", 0, self.max_frame)
        out = ffi.new("uint8_t[]", self.max_frame)
        n = self._c.encode(out, self.max_frame, ffi.new("unsigned[]", values + [0]), data, len(data))
        if n == 0:
            raise InvalidValueError(f"{self.name}: no frame has fields {dict(zip(self.fields, values))} "
                                    f"and {len(data)} data bytes")
        return bytes(ffi.buffer(out, n))

    def __repr__(self) -> str:
        return f"<Codec {self.name} fields={self.fields}>"


class Decoder:
    """A row's decoder on one stream: ``feed``, ``tick`` on a quiet line, ``finish`` at the end."""

    __slots__ = ("codec", "_state", "_out", "_handle", "_feed", "_tick", "_finish", "_deadline",
                 "_n", "_frame_name", "_frame_names", "_make_frame", "_make_reject", "__weakref__")

    def __init__(self, codec: Codec, baud: int = 0, gap_ns: int = 0,
                 frame: Optional[FrameBuilder] = None, reject: Optional[RejectBuilder] = None) -> None:
        if not isinstance(codec, Codec):
            raise InvalidTypeError(f"codec must be a Codec, not {type(codec).__name__}")
        check_int(baud, "baud", 0, U32)
        check_int(gap_ns, "gap_ns", 0, NS_MAX)
        for what, fn in (("frame", frame), ("reject", reject)):
            if fn is not None and not callable(fn):
                raise InvalidTypeError(f"{what} must be None or callable, not {type(fn).__name__}")
        names = codec.fields
        self._make_frame: FrameBuilder = frame or (
            lambda off, raw, data, values, name: Frame(off, raw, data, dict(zip(names, values)), name))
        self._make_reject: RejectBuilder = reject or (
            lambda off, raw, code, reason: Reject(off, raw, code, reason))
        c = codec._c
        self.codec = codec
        self._state = ffi.new("uint8_t[]", c.state_size)
        c.init(self._state, baud, gap_ns)
        self._out: List[Any] = []
        self._handle = ffi.new_handle(self)
        self._feed, self._tick, self._finish, self._deadline = c.feed, c.tick, c.finish, c.deadline
        self._n = len(codec.fields)
        self._frame_name = c.frame_name
        self._frame_names: Dict[Tuple[int, ...], Optional[str]] = {}   # by header fields

    def _take(self) -> List[Any]:
        out, self._out = self._out, []
        return out

    def feed(self, data: bytes, now_ns: int = 0) -> List[Any]:
        """Decode bytes (any bytes-like object) that arrived at ``now_ns``."""
        data = check_bytes(data, "data", 0, 2**62)
        check_int(now_ns, "now_ns", 0, NS_MAX)
        self._feed(self._state, data, len(data), now_ns, lib.fap_py_codec_frame,
                   lib.fap_py_codec_reject, self._handle)
        return self._take()

    def deadline(self) -> Optional[int]:
        """When :meth:`tick` would abandon a held partial frame (monotonic ns), or None."""
        d = self._deadline(self._state)
        return None if d == lib.FAP_CODEC_NEVER else int(d)

    def tick(self, now_ns: int) -> List[Any]:
        """The line is quiet at ``now_ns``: the inter-byte gap, and garbage known so far."""
        check_int(now_ns, "now_ns", 0, NS_MAX)
        self._tick(self._state, now_ns, lib.fap_py_codec_frame, lib.fap_py_codec_reject,
                   self._handle)
        return self._take()

    def finish(self) -> List[Any]:
        """End of input: a held partial frame is "truncated"; offsets run on after it."""
        self._finish(self._state, lib.fap_py_codec_frame, lib.fap_py_codec_reject, self._handle)
        return self._take()

    def _on_frame(self, f: "ffi.CData") -> None:
        values = tuple(f.field[0:self._n])
        try:
            name = self._frame_names[values]
        except KeyError:
            if len(self._frame_names) > 4096:   # many distinct headers: keep it bounded
                self._frame_names.clear()
            c_name = self._frame_name(f)
            name = self._frame_names[values] = \
                ffi.string(c_name).decode() if c_name != ffi.NULL else None
        self._out.append(self._make_frame(
            f.offset, bytes(ffi.buffer(f.raw, f.raw_len)),
            bytes(ffi.buffer(f.data, f.data_len)) if f.data_len else b"", values, name))

    def _on_reject(self, code: int, raw: "ffi.CData", n: int, offset: int) -> None:
        self._out.append(self._make_reject(offset, bytes(ffi.buffer(raw, n)), code,
                                           self.codec.reject_name(code)))


@ffi.def_extern()
def fap_py_codec_frame(ctx: "ffi.CData", f: "ffi.CData") -> None:
    ffi.from_handle(ctx)._on_frame(f)


@ffi.def_extern()
def fap_py_codec_reject(ctx: "ffi.CData", code: int, raw: "ffi.CData", n: int, offset: int) -> None:
    ffi.from_handle(ctx)._on_reject(code, raw, n, offset)


def _rows() -> Dict[str, Codec]:
    rows: Dict[str, Codec] = {}
    i = 0
    while True:
        row = lib.fap_codec_at(i)
        if row == ffi.NULL:
            return rows
        codec = Codec(row)
        rows[codec.name] = codec
        i += 1


_ROWS = _rows()


def names() -> Tuple[str, ...]:
    """The names of the table's rows, in table order."""
    return tuple(_ROWS)


def find(name: str) -> Codec:
    """The row called ``name`` (or an alias the table accepts: "execasync");
    InvalidValueError when there is none."""
    if not isinstance(name, str):
        raise InvalidTypeError(f"codec name must be a str, not {type(name).__name__}")
    row = lib.fap_codec_find(name.encode("utf-8", "replace")) if "\0" not in name else ffi.NULL
    if row == ffi.NULL:
        raise InvalidValueError(f"no C codec {name!r} (codecs: {', '.join(_ROWS)})")
    return _ROWS[ffi.string(row.name).decode()]
