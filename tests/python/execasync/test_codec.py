"""Exec async framing from Python: byte-exact against the shared vectors."""
from __future__ import annotations

import pytest

from fap_py.errors import InvalidValueError
from fap_py.execasync import MAX_FRAME, Decoder, ExecValueError, Status, encode


def test_encode_matches_every_vector(vectors: dict) -> None:
    assert len(vectors["valid"]) == 7
    for v in vectors["valid"]:
        frame = encode(v["node"], bytes.fromhex(v["data"]), v["seq"])
        assert frame.hex() == v["frame"], v["name"]
        assert len(frame) <= 2 * len(bytes.fromhex(v["data"])) + 8


def test_node_and_seq_dle_sent_unstuffed() -> None:
    assert encode(0x10, b"\x10", 0x10).hex() == "10021010101010030909"


def test_worst_case_is_2n_plus_8() -> None:
    assert len(encode(3, b"\x10" * 16, 255)) == 2 * 16 + 8
    assert len(encode(3, b"\x10" * 255, 1)) == MAX_FRAME == 518


def test_decode_every_vector(vectors: dict) -> None:
    for v in vectors["valid"]:
        frames = Decoder().feed(bytes.fromhex(v["frame"]))
        assert len(frames) == 1, v["name"]
        f = frames[0]
        assert f.ok and (f.node, f.seq, f.data.hex()) == (v["node"], v["seq"], v["data"])


def test_invalid_vector_is_bad_crc(vectors: dict) -> None:
    (v,) = vectors["invalid"]
    (f,) = Decoder().feed(bytes.fromhex(v["frame"]))
    assert v["reason"] == "crc"
    assert f.status is Status.BAD_CRC and not f.ok


def test_stream_with_noise_and_split_reads(vectors: dict) -> None:
    stream = b"".join(b"\x00\x10\x55" + bytes.fromhex(v["frame"]) for v in vectors["valid"])
    dec = Decoder()
    frames = []
    for i in range(0, len(stream), 5):          # reads are not frame boundaries
        frames += dec.feed(stream[i:i + 5])
    assert [f.data.hex() for f in frames] == [v["data"] for v in vectors["valid"]]


def test_overflow_then_next_frame() -> None:
    dec = Decoder(buffer_size=4)
    frames = dec.feed(encode(1, b"abcdefgh", 1) + encode(1, b"xy", 2))
    assert [f.status for f in frames] == [Status.OVERFLOW, Status.GOOD]
    assert frames[0].data == b"abcd" and frames[1].data == b"xy"


def test_framing_error_reported() -> None:
    (f,) = Decoder().feed(bytes.fromhex("10020101411005"))
    assert f.status is Status.FRAMING


def test_bad_arguments() -> None:
    with pytest.raises(ExecValueError):
        encode(1, b"x" * 256)
    with pytest.raises(InvalidValueError):
        encode(256, b"")
    with pytest.raises(ValueError):
        Decoder(buffer_size=0)
