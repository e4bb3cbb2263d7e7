"""The mikroC codec through fap_py.mikroc: vectors byte-exact, errors typed."""
from __future__ import annotations

import random

import pytest

from fap_py.errors import FrameError, InvalidValueError
from fap_py.mikroc import (
    BROADCAST,
    AbortedFrameError,
    ChecksumError,
    Decoder,
    FormatError,
    LongFrameError,
    Message,
    MikrocFrameError,
    ShortFrameError,
    decode,
    encode,
)


def test_vectors_count(vectors):
    assert len(vectors["valid"]) == 10
    assert len(vectors["invalid"]) == 2
    assert vectors["broadcast_address"] == BROADCAST
    captured = [v for v in vectors["valid"] if v["source"].startswith("captured")]
    assert len(captured) == 5


def test_encode_vectors_byte_exact(vectors):
    for v in vectors["valid"]:
        frame = encode(v["address"], bytes.fromhex(v["data"]), from_master=v["master"])
        assert frame.hex() == v["frame"], v["name"]


def test_decode_vectors(vectors):
    for v in vectors["valid"]:
        msg = decode(bytes.fromhex(v["frame"]))
        assert msg == Message(v["address"], bytes.fromhex(v["data"]), v["master"]), v["name"]


def test_invalid_vectors_raise_typed_errors(vectors):
    kinds = {"crc": ChecksumError, "datalen": FormatError}
    for v in vectors["invalid"]:
        with pytest.raises(kinds[v["reason"]]) as info:
            decode(bytes.fromhex(v["frame"]))
        assert isinstance(info.value, FrameError)
        assert info.value.address == bytes.fromhex(v["frame"])[1]


def test_encode_rejects_bad_arguments():
    with pytest.raises(InvalidValueError):
        encode(1, b"\x01\x02\x03\x04")
    with pytest.raises(InvalidValueError):
        encode(256, b"")
    with pytest.raises(InvalidValueError):
        encode(-1, b"")


def test_chunking_and_noise_do_not_matter(vectors):
    frames = [bytes.fromhex(v["frame"]) for v in vectors["valid"]]
    noise = [b"", b"\x00", b"\xa9\xa9", b"\x55\xff\x13"]
    rng = random.Random(1)
    stream = b"".join(rng.choice(noise) + f for f in frames)
    expected = [decode(f) for f in frames]
    for _ in range(50):
        d = Decoder()
        events = []
        pos = 0
        while pos < len(stream):
            n = rng.randint(1, 9)
            events += d.feed(stream[pos:pos + n])
            pos += n
        assert events == expected


def test_resync_short_long_frames():
    good = encode(160, b"\x02")
    events = Decoder().feed(b"\x96\xa0\x83\x11" + good)          # cut off
    assert isinstance(events[0], AbortedFrameError) and events[0].address == 160
    assert events[1] == Message(160, b"\x02", True)
    events = Decoder().feed(bytes.fromhex("96108301" "6da9") + good)  # stop too early
    assert isinstance(events[0], ShortFrameError)
    assert events[1] == decode(good)
    events = Decoder().feed(bytes.fromhex("9610810102" "6da9") + good)  # too long
    assert isinstance(events[0], LongFrameError)
    assert events[1] == decode(good)
    assert all(isinstance(e, MikrocFrameError) for e in events[:1])


def test_roundtrip_all_addresses():
    for address in range(256):
        for data in (b"", b"\x96", b"\xa9\x96", b"\x00\xa9\xff"):
            for master in (True, False):
                frame = encode(address, data, from_master=master)
                assert 0x96 not in frame[1:-1] and 0xA9 not in frame[1:-1]
                assert decode(frame) == Message(address, data, master)


def test_wrong_argument_types_are_fap_errors() -> None:
    from fap_py.errors import InvalidValueError
    from fap_py.mikroc import encode

    for bad_data in (3, "abc", [1, 2]):
        with pytest.raises(InvalidValueError):
            encode(7, bad_data)  # type: ignore[arg-type]
    for bad_address in (True, 1.0, "7", 256, -1):
        with pytest.raises(InvalidValueError):
            encode(bad_address, b"")  # type: ignore[arg-type]
