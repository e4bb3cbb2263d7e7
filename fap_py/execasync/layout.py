"""StructLayout: a C structure's native layout <-> exec async's packed big-endian form."""
from __future__ import annotations

import ctypes
from typing import Any, Dict, List, Mapping, Sequence, Tuple, Union

from .._native import ffi, lib
from .._validate import check_bytes, check_int
from .codec import BytesLike
from .errors import (
    _ERR,
    ExecTypeError,
    ExecValueError,
)

# ---- structure packing -----------------------------------------------------------

_CTYPES: Dict[str, Any] = {
    "u8": ctypes.c_uint8, "s8": ctypes.c_int8,
    "u16": ctypes.c_uint16, "s16": ctypes.c_int16,
    "u32": ctypes.c_uint32, "s32": ctypes.c_int32,
    "u64": ctypes.c_uint64, "s64": ctypes.c_int64,
    "f32": ctypes.c_float, "f64": ctypes.c_double,
    "bytes": ctypes.c_char,          # count = length; copied as is
}

FieldSpec = Union[Tuple[str, str], Tuple[str, str, int]]


class StructLayout:
    """A C structure described in Python, packed by the C core.

    ``fields`` lists ``(name, type)`` or ``(name, type, count)`` in member
    order; types are ``u8 s8 u16 s16 u32 s32 u64 s64 f32 f64`` and
    ``bytes`` (count = its length). The native layout (offsets, padding) is
    the platform C compiler's, as ``ctypes`` computes it; the descriptor
    handed to ``execPackDataEx`` is built from it, so the packed bytes are
    what a C program with the same struct sends::

        layout = StructLayout([("id", "u8"), ("raw", "u16"), ("delta", "s16", 3)])
        wire = layout.pack({"id": 1, "raw": 0x1234, "delta": [1, -1, 0]})
        layout.unpack(wire)["raw"] == 0x1234
    """

    def __init__(self, fields: Sequence[FieldSpec]) -> None:
        if isinstance(fields, (str, bytes)) or not isinstance(fields, Sequence):
            raise ExecTypeError(f"fields must be a sequence of tuples, not {type(fields).__name__}")
        if not fields:
            raise ExecValueError("a structure needs at least one field")
        specs: List[Tuple[str, str, int]] = []
        for f in fields:
            if not isinstance(f, tuple) or len(f) not in (2, 3):
                raise ExecValueError(f"field {f!r}: expected (name, type[, count])")
            name, kind = f[0], f[1]
            if not isinstance(name, str) or not name.isidentifier() or name.startswith("_"):
                raise ExecValueError(f"field name {name!r} must be an identifier")
            if not isinstance(kind, str):
                raise ExecTypeError(f"field {name!r}: type must be a str, not {type(kind).__name__}")
            count = check_int(f[2], f"field {name!r} count", 1, 0xFFFF, **_ERR) if len(f) == 3 else 1
            if kind not in _CTYPES:
                raise ExecValueError(f"field {name!r}: unknown type {kind!r} "
                                     f"(one of {' '.join(_CTYPES)})")
            if count < 1:
                raise ExecValueError(f"field {name!r}: count {count} < 1")
            specs.append((name, kind, count))
        names = [s[0] for s in specs]
        if len(set(names)) != len(names):
            raise ExecValueError("field names must be unique")
        ctype_fields = [(n, _CTYPES[k] * c if (c > 1 or k == "bytes") else _CTYPES[k])
                        for n, k, c in specs]
        self._struct: Any = type("ExecStruct", (ctypes.Structure,), {"_fields_": ctype_fields})
        self._specs = specs
        self.native_size = ctypes.sizeof(self._struct)
        if self.native_size > 0xFFFF:
            raise ExecValueError("structure larger than 65535 bytes")
        self._desc = ffi.new("struct execStructDef[]", len(specs) + 1)
        for i, (name, kind, count) in enumerate(specs):
            d = self._desc[i]
            d.Offset = getattr(self._struct, name).offset
            d.Size = ctypes.sizeof(_CTYPES[kind])
            d.Count = count
        self._desc[len(specs)].Offset = self.native_size   # terminator: Size 0
        self.packed_size = sum(ctypes.sizeof(_CTYPES[k]) * c for _, k, c in specs)

    @property
    def names(self) -> List[str]:
        return [s[0] for s in self._specs]

    def pack_native(self, native: BytesLike) -> bytes:
        """Native-layout bytes (e.g. a cffi/ctypes struct) -> packed big-endian."""
        native = check_bytes(native, "native", 0, 1 << 62, **_ERR)
        if len(native) != self.native_size:
            raise ExecValueError(f"{len(native)} bytes, the native structure has {self.native_size}")
        src = ffi.new("byte[]", native)
        out = ffi.new("byte[]", max(self.packed_size, 1))
        n = lib.execPackDataEx(out, src, self._desc)
        return bytes(ffi.buffer(out, n))

    def unpack_native(self, packed: BytesLike) -> bytes:
        """Packed big-endian -> native-layout bytes (padding zero)."""
        packed = check_bytes(packed, "packed", 0, 1 << 62, **_ERR)
        if len(packed) != self.packed_size:
            raise ExecValueError(f"{len(packed)} bytes, the packed structure has {self.packed_size}")
        src = ffi.new("byte[]", packed)
        out = ffi.new("byte[]", self.native_size)   # zeroed: padding stays 0
        n = lib.execUnPackDataEx(out, src, self._desc)
        return bytes(ffi.buffer(out, n))

    def pack(self, values: Mapping[str, Any]) -> bytes:
        """Field values (ints, floats, lists for arrays, bytes) -> packed bytes."""
        if not isinstance(values, Mapping):
            raise ExecTypeError(f"values must be a mapping, not {type(values).__name__}")
        missing = [n for n in self.names if n not in values]
        extra = [n for n in values if n not in self.names]
        if missing or extra:
            raise ExecValueError(f"missing fields {missing}, unknown fields {extra}")
        inst = self._struct()
        for name, kind, count in self._specs:
            v = values[name]
            try:
                if kind == "bytes":
                    v = check_bytes(v, f"field {name!r}", 0, count, **_ERR)
                    if len(v) > count:
                        raise ExecValueError(f"field {name!r}: {len(v)} bytes, room for {count}")
                    ctypes.memmove(ctypes.addressof(inst) + getattr(self._struct, name).offset,
                                   v, len(v))
                elif count > 1:
                    if isinstance(v, (str, bytes)) or not isinstance(v, Sequence):
                        raise ExecTypeError(f"field {name!r}: expected a sequence of {count}")
                    if len(v) != count:
                        raise ExecValueError(f"field {name!r}: {len(v)} items, expected {count}")
                    arr = getattr(inst, name)
                    for i, item in enumerate(v):
                        arr[i] = _checked(name, kind, item)
                else:
                    setattr(inst, name, _checked(name, kind, v))
            except (TypeError, OverflowError) as exc:
                raise ExecValueError(f"field {name!r}: {exc}") from None
        return self.pack_native(bytes(inst))

    def unpack(self, packed: BytesLike) -> Dict[str, Any]:
        """Packed bytes -> dict of field values (lists for arrays)."""
        inst = self._struct.from_buffer_copy(self.unpack_native(packed))
        out: Dict[str, Any] = {}
        for name, kind, count in self._specs:
            v = getattr(inst, name)
            if kind == "bytes":
                off = getattr(self._struct, name).offset
                out[name] = bytes(inst)[off:off + count]
            elif count > 1:
                out[name] = list(v)
            else:
                out[name] = v
        return out


def _checked(name: str, kind: str, value: Any) -> Any:
    """Range-check an integer (ctypes would silently wrap it)."""
    if kind[0] == "f":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ExecTypeError(f"field {name!r}: {value!r} is not a number")
        try:
            return float(value)
        except OverflowError:
            raise ExecValueError(f"field {name!r}: {value} does not fit a float") from None
    if not isinstance(value, int) or isinstance(value, bool):
        raise ExecTypeError(f"field {name!r}: {value!r} is not an int")
    bits = int(kind[1:])
    lo, hi = (0, (1 << bits) - 1) if kind[0] == "u" else (-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    if not lo <= value <= hi:
        raise ExecValueError(f"field {name!r}: {value} out of range {lo}..{hi} ({kind})")
    return value
