"""StructLayout: a Python description packed by execPackDataEx and back."""
from __future__ import annotations

import ctypes

import pytest

from fap_py.execasync import ExecValueError, StructLayout

FIELDS = [("a", "u8"), ("b", "u16"), ("c", "u8"), ("d", "u32"), ("e", "s32"),
          ("tag", "bytes", 3), ("f", "s16", 2), ("g", "u64")]
VALUES = {"a": 0x12, "b": 0xABCD, "c": 0x7F, "d": 0x01020304, "e": -2,
          "tag": b"xyz", "f": [-32768, 16], "g": 0x0123456789ABCDEF}
WIRE = bytes.fromhex("12" "abcd" "7f" "01020304" "fffffffe") + b"xyz" + \
    bytes.fromhex("8000" "0010" "0123456789abcdef")


def test_padding_exists_natively() -> None:
    layout = StructLayout(FIELDS)
    assert layout.packed_size == 27
    assert layout.native_size > layout.packed_size


def test_pack_is_packed_big_endian() -> None:
    assert StructLayout(FIELDS).pack(VALUES) == WIRE


def test_round_trip() -> None:
    layout = StructLayout(FIELDS)
    assert layout.unpack(layout.pack(VALUES)) == VALUES


def test_extremes_round_trip() -> None:
    layout = StructLayout([("u8", "u8"), ("u16", "u16"), ("u32", "u32"), ("s32", "s32")])
    for vals in ({"u8": 0, "u16": 0, "u32": 0, "s32": -(2 ** 31)},
                 {"u8": 255, "u16": 65535, "u32": 2 ** 32 - 1, "s32": 2 ** 31 - 1}):
        wire = layout.pack(vals)
        assert len(wire) == 11
        assert layout.unpack(wire) == vals


def test_native_bytes_match_a_c_struct() -> None:
    class C(ctypes.Structure):
        _fields_ = [("a", ctypes.c_uint8), ("b", ctypes.c_uint16), ("e", ctypes.c_int32)]

    layout = StructLayout([("a", "u8"), ("b", "u16"), ("e", "s32")])
    native = bytes(C(1, 0x0203, -1))
    assert layout.pack_native(native) == bytes.fromhex("01" "0203" "ffffffff")
    assert layout.unpack_native(bytes.fromhex("01" "0203" "ffffffff")) == native


def test_bad_descriptions_and_values() -> None:
    with pytest.raises(ExecValueError):
        StructLayout([])
    with pytest.raises(ExecValueError):
        StructLayout([("x", "u12")])
    with pytest.raises(ExecValueError):
        StructLayout([("x", "u8"), ("x", "u8")])
    layout = StructLayout([("x", "u8"), ("y", "s16", 2)])
    with pytest.raises(ExecValueError):
        layout.pack({"x": 256, "y": [0, 0]})
    with pytest.raises(ExecValueError):
        layout.pack({"x": 1})
    with pytest.raises(ExecValueError):
        layout.pack({"x": 1, "y": [0]})
    with pytest.raises(ValueError):
        layout.unpack(b"\x00")
