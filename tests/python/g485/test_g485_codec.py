"""G485 codec: the 8 packet types against the vectors, range checks, the streaming parser."""
from __future__ import annotations

import random

import pytest

from fap_py.errors import FrameError, InvalidValueError
from fap_py.g485 import codec
from fap_py.g485.codec import (
    Discarded,
    ErrorBit,
    Packet,
    PacketKind,
    ParseIssue,
    Parser,
    SetCommand,
    decode_frame,
    describe_error_word,
)
from fap_py.g485.errors import (
    BroadcastReadError,
    CheckByteError,
    G485FrameError,
    G485ValueError,
    UnexpectedReplyError,
)

# how each vector is built by the encoders (same order as the file)
ENCODED = {
    "User-Register-Write slave 1 reg 13, 10 x 0x32": lambda: codec.encode_write(1, 13, [0x32] * 10),
    "User-Register-Read-Request slave 1 reg 1 count 31": lambda: codec.encode_read_request(1, 1, 31),
    "Set 0x7C (save to EEPROM) slave 1": lambda: codec.encode_set(1, SetCommand.SAVE_EEPROM),
    "broadcast Set 0x77 (apply non-real-time writes)": lambda: codec.encode_set(0, SetCommand.APPLY_WRITES),
    "Get-Error-Word-Request slave 5": lambda: codec.encode_error_word_request(5),
    "Handshake-Request slave 1": lambda: codec.encode_handshake_request(1),
    "User-Register-Read-Response 3 bytes": lambda: codec.encode_read_response(1, b"\x01\x02\x03"),
    "Get-Error-Word-Response ERRH=0x12 ERRL=0x34": lambda: codec.encode_error_word_response(0x1234),
    "Handshake-Response carrying 0x7f": lambda: codec.encode_handshake_response(0x7F),
    "broadcast write reg 8 = 0x05": lambda: codec.encode_write(0, 8, 5),
}

DECODED = {
    "User-Register-Write slave 1 reg 13, 10 x 0x32": (PacketKind.WRITE, 1, 13, b"\x32" * 10),
    "User-Register-Read-Request slave 1 reg 1 count 31": (PacketKind.READ_REQUEST, 1, 1, b"\x1f"),
    "Set 0x7C (save to EEPROM) slave 1": (PacketKind.SET, 1, 0x7C, b""),
    "broadcast Set 0x77 (apply non-real-time writes)": (PacketKind.SET, 0, 0x77, b""),
    "Get-Error-Word-Request slave 5": (PacketKind.ERROR_WORD_REQUEST, 5, 0x7E, b""),
    "Handshake-Request slave 1": (PacketKind.HANDSHAKE_REQUEST, 1, 0x7F, b""),
    "User-Register-Read-Response 3 bytes": (PacketKind.READ_RESPONSE, 127, 1, b"\x01\x02\x03"),
    "Get-Error-Word-Response ERRH=0x12 ERRL=0x34": (PacketKind.ERROR_WORD_RESPONSE, 127, 0x7E, b"\x12\x34"),
    "Handshake-Response carrying 0x7f": (PacketKind.HANDSHAKE_RESPONSE, 127, 0x7F, b"\x7f"),
    "broadcast write reg 8 = 0x05": (PacketKind.WRITE, 0, 8, b"\x05"),
}


def test_vectors_cover_all_eight_packet_types(vectors):
    kinds = {decode_frame(bytes.fromhex(v["frame"])).kind for v in vectors}
    assert kinds == set(PacketKind)


def test_every_vector_encodes_byte_exact(vectors):
    assert len(vectors) == len(ENCODED)
    for v in vectors:
        assert ENCODED[v["name"]]().hex() == v["frame"], v["name"]


def test_every_vector_decodes(vectors):
    for v in vectors:
        frame = bytes.fromhex(v["frame"])
        pkt = decode_frame(frame)
        assert (pkt.kind, pkt.address, pkt.pid, pkt.data) == DECODED[v["name"]], v["name"]
        assert pkt.check == frame[-1] and pkt.raw == frame


def test_packet_accessors():
    assert decode_frame(codec.encode_error_word_response(0xBEEF)).error_word == 0xBEEF
    assert decode_frame(codec.encode_handshake_response(0x42)).handshake_value == 0x42
    req = decode_frame(codec.encode_read_request(9, 20, 4))
    assert (req.register, req.read_count) == (20, 4)
    assert decode_frame(codec.encode_set(3, "reset")).command is SetCommand.RESET


def test_replies_start_ff_ff_ff():
    for frame in (codec.encode_read_response(8, b"\x00"), codec.encode_handshake_response(0),
                  codec.encode_error_word_response(0)):
        assert frame[:3] == b"\xff\xff\xff"


def test_all_ten_set_commands_by_name_value_and_member():
    assert len(SetCommand) == 10
    assert {int(c) for c in SetCommand} == set(range(0x74, 0x7E))
    for cmd in SetCommand:
        frame = codec.encode_set(7, cmd.name.lower())
        assert frame == codec.encode_set(7, int(cmd)) == codec.encode_set(7, cmd)
        assert frame[-1] == ~(14 + 2 + int(cmd)) & 0xFF
    with pytest.raises(G485ValueError, match="unknown Set command"):
        codec.encode_set(1, "warp_speed")
    with pytest.raises(G485ValueError, match="0x74..0x7d"):
        codec.encode_set(1, 0x73)


@pytest.mark.parametrize("call, match", [
    (lambda: codec.encode_read_request(0, 1, 1), "broadcast"),
    (lambda: codec.encode_handshake_request(0), "broadcast"),
    (lambda: codec.encode_error_word_request(0), "broadcast"),
])
def test_broadcast_read_refused(call, match):
    with pytest.raises(BroadcastReadError, match=match) as info:
        call()
    assert isinstance(info.value, InvalidValueError) and isinstance(info.value, ValueError)


@pytest.mark.parametrize("call", [
    lambda: codec.encode_write(127, 8, 1),
    lambda: codec.encode_write(-1, 8, 1),
    lambda: codec.encode_read_request(127, 1, 1),
    lambda: codec.encode_write(1, 0, 1),
    lambda: codec.encode_write(1, 101, 1),
    lambda: codec.encode_write(1, 99, [1, 2, 3]),
    lambda: codec.encode_write(1, 8, b""),
    lambda: codec.encode_write(1, 8, [256]),
    lambda: codec.encode_read_request(1, 1, 0),
    lambda: codec.encode_read_request(1, 50, 52),
    lambda: codec.encode_read_request(1, 1, 101),
    lambda: codec.encode_handshake_response(256),
    lambda: codec.encode_error_word_response(0x10000),
    lambda: codec.encode_write(True, 8, 1),
])
def test_range_checks(call):
    with pytest.raises(G485ValueError):
        call()


def test_largest_frames():
    frame = codec.encode_write(126, 1, bytes(range(100)))
    assert frame[3] == 102 and decode_frame(frame).data == bytes(range(100))
    assert decode_frame(codec.encode_read_request(1, 100, 1)).read_count == 1


def test_decode_reports_what_is_wrong():
    good = codec.encode_read_response(1, b"\x01\x02\x03")
    with pytest.raises(CheckByteError, match="bad check byte 0xf5, expected 0xf4"):
        decode_frame(good[:-1] + b"\xf5")
    with pytest.raises(G485FrameError, match="length byte 5 but 4 bytes"):
        decode_frame(good[:-1])
    with pytest.raises(G485FrameError, match="must start FF FF"):
        decode_frame(b"\xfe" + good[1:])
    unknown = b"\xff\xff\x02\x02\x70" + bytes((~(2 + 2 + 0x70) & 0xFF,))
    with pytest.raises(UnexpectedReplyError, match="PID 0x70"):
        decode_frame(unknown)
    assert issubclass(CheckByteError, FrameError)


def test_error_word_description():
    assert describe_error_word(0) == "none"
    text = describe_error_word(ErrorBit.READ_ONLY | ErrorBit.BAD_CHECK | 0x0100)
    assert "READ_ONLY" in text and "BAD_CHECK" in text and "device-specific 0x0100" in text


# -- streaming parser -----------------------------------------------------------

def _frames(vectors):
    return [bytes.fromhex(v["frame"]) for v in vectors]


def _packets(events):
    return [e.raw for e in events if isinstance(e, Packet)]


def test_parser_stream_in_one_piece_and_byte_by_byte(vectors):
    frames = _frames(vectors)
    stream = b"".join(frames)
    assert _packets(Parser().feed(stream)) == frames
    p = Parser()
    got = []
    for b in stream:
        got += p.feed(bytes((b,)))
    assert _packets(got) == frames and all(isinstance(e, Packet) for e in got)
    assert p.buffered == 0


def test_parser_random_chunks_and_garbage(vectors):
    rng = random.Random(485)
    frames = _frames(vectors) * 20
    rng.shuffle(frames)
    stream = bytearray()
    garbage = 0
    for f in frames:
        junk = bytes(rng.randrange(0, 0xFF) for _ in range(rng.randrange(0, 6)))  # no 0xFF
        garbage += len(junk)
        stream += junk + f
    p = Parser()
    events = []
    pos = 0
    while pos < len(stream):
        n = rng.randrange(1, 40)
        events += p.feed(bytes(stream[pos:pos + n]))
        pos += n
    assert _packets(events) == frames
    dropped = [e for e in events if isinstance(e, Discarded)]
    assert sum(len(e.data) for e in dropped) == garbage
    assert all(e.issue is ParseIssue.GARBAGE for e in dropped)


def test_parser_reply_after_extra_ff_bytes():
    reply = codec.encode_read_response(8, b"\xff\xff\xff")  # data full of 0xFF too
    for prefix in (b"\xff", b"\xff\xff", b"\xff\xff\xff", b"\x00\xff"):
        events = Parser().feed(prefix + reply)
        assert _packets(events) == [reply], prefix


def test_parser_wake_up_preamble_then_request():
    request = codec.encode_handshake_request(1)
    p = Parser()
    events = p.feed(codec.WAKE_UP_PREAMBLE)
    assert all(isinstance(e, Discarded) for e in events)
    events += p.feed(request)
    assert _packets(events) == [request]
    assert p.buffered == 0


def test_parser_bad_check_is_reported_and_next_frame_found():
    good = codec.encode_error_word_response(0x0102)
    bad = bytearray(good)
    bad[5] ^= 0x10
    events = Parser().feed(bytes(bad) + good)
    assert _packets(events) == [good]
    issues = [e for e in events if isinstance(e, Discarded) and e.issue is ParseIssue.BAD_CHECK]
    assert issues and issues[0].data == bytes(bad) and "expected" in issues[0].detail


def test_parser_impossible_length_and_master_write_address():
    p = Parser()
    events = p.feed(b"\xff\xff\x02\x01\x00" + b"\xff\xff\xfe\x02\x7c\x00")
    assert {e.issue for e in events if isinstance(e, Discarded)} <= {ParseIssue.BAD_LENGTH, ParseIssue.GARBAGE}
    assert any(e.issue is ParseIssue.BAD_LENGTH for e in events)
    assert not _packets(events)


def test_parser_unknown_packet_with_good_check_is_skipped_whole():
    unknown = b"\xff\xff\x02\x02\x70" + bytes((~(2 + 2 + 0x70) & 0xFF,))
    good = codec.encode_set(1, SetCommand.RESET)
    events = Parser().feed(unknown + good)
    assert events[0].issue is ParseIssue.UNKNOWN_PACKET and events[0].data == unknown
    assert _packets(events) == [good]


def test_parser_corrupted_length_swallowing_next_frame_is_recovered_by_expire():
    damaged = codec.encode_handshake_request(1)[:3] + b"\x60"  # a header claiming 96 more bytes
    good = codec.encode_handshake_request(2)
    p = Parser()
    assert _packets(p.feed(damaged + good)) == []
    assert p.pending_header() == (0x03, 0x60)
    assert p.bytes_wanted() == 4 + 0x60 - len(damaged + good)
    events = p.expire()
    assert _packets(events) == [good]
    assert events[0].issue is ParseIssue.STALE
    assert p.buffered == 0


def test_parser_bytes_wanted_guides_exact_reads():
    reply = codec.encode_read_response(1, bytes(10))
    p = Parser()
    assert p.bytes_wanted() == 0
    p.feed(reply[:2])
    assert p.bytes_wanted() == 2
    p.feed(reply[2:5])
    assert p.bytes_wanted() == len(reply) - 5
    assert _packets(p.feed(reply[5:])) == [reply]


def test_fast_paths_agree_with_the_parser(vectors):
    """exact_packet / is_exact_reply accept exactly what the Parser returns whole, nothing else."""
    rng = random.Random(4851)
    chunks = list(_frames(vectors))
    for f in list(chunks):
        chunks += [f[:-1], f + b"\x00", b"\x00" + f, f[:-1] + bytes(((f[-1] + 1) & 0xFF,)), f + f,
                   bytes(rng.randrange(256) for _ in range(len(f)))]
        for _ in range(5):  # one damaged byte somewhere
            i = rng.randrange(len(f))
            chunks.append(f[:i] + bytes(((f[i] ^ (1 << rng.randrange(8))),)) + f[i + 1:])
    chunks += [codec.WAKE_UP_PREAMBLE + codec.encode_handshake_request(1), b"\xff\xff\xfe\x02\x7f\x80", b""]
    for chunk in chunks:
        events = Parser().feed(chunk)
        whole = events[0] if len(events) == 1 and isinstance(events[0], Packet) and \
            events[0].raw == chunk else None
        assert codec.exact_packet(chunk) == whole, chunk.hex(" ")
        for pid, length in ((1, 5), (1, 12), (codec.HPID, 3), (codec.EPID, 4), (8, 5)):
            prefix = codec.reply_prefix(pid, length)
            expected = whole is not None and whole.kind in codec.REPLY_KINDS and whole.pid == pid \
                and len(whole.raw) == codec.HEADER_SIZE + length
            assert codec.is_exact_reply(chunk, prefix) == expected, (chunk.hex(" "), pid, length)


def test_frame_sum_is_the_check_byte_rule(vectors):
    for f in _frames(vectors):
        assert sum(f) & 0xFF == codec.FRAME_SUM
        assert codec.check_byte(f[2:-1]) == f[-1]
        assert sum(f[:-1] + bytes(((f[-1] + 1) & 0xFF,))) & 0xFF != codec.FRAME_SUM
