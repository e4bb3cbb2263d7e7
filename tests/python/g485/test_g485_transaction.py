"""The sans-I/O G485 transaction (fap_py.g485.transaction): events and a clock in, actions out.

No port, no thread, no sleep: every test feeds bytes and times by hand and
looks at the Send / Wait / Done / Fail actions and the counters.
"""
from __future__ import annotations

import dataclasses

import pytest

from fap_py.g485 import codec
from fap_py.g485.errors import (
    CheckByteError,
    G485ValueError,
    HandshakeMismatchError,
    NoResponseError,
    WriteRefusedError,
)
from fap_py.g485.transaction import Check, Done, Fail, MasterStats, Send, Session, Wait

BAUD = 9600  # below the wake-up threshold: no preamble unless asked
BYTE = 10.0 / BAUD


def session(**kw) -> Session:
    s = Session(**{"timeout": 0.1, "retries": 0, "check": "none", **kw})
    s.attach("test-port", BAUD)
    return s


def test_read_without_check_is_one_send_then_done() -> None:
    s = session()
    tx = s.read(3, 1, 10)
    act = tx.start(100.0)
    request = codec.encode_read_request(3, 1, 10)
    assert isinstance(act, Send) and act.wire == request and act.size == 6 + 10
    # the timeout plus the request's and the reply's wire time
    assert act.deadline == pytest.approx(100.0 + 0.1 + (len(request) + 16) * BYTE)
    reply = codec.encode_read_response(1, bytes(range(10)))
    assert tx.receive(reply, 100.01) == Done(bytes(range(10)))
    assert s.stats == MasterStats(transactions=1)
    assert s.believed_check_byte(3) == reply[-1]


def test_reply_in_pieces_waits_with_the_same_deadline() -> None:
    s = session()
    tx = s.read(3, 8, 2)
    send = tx.start(0.0)
    reply = codec.encode_read_response(8, b"\x05\x06")
    act = tx.receive(reply[:3], 0.001)
    # the rest of the reply at once (the read never goes past the reply's end), not just the header
    assert isinstance(act, Wait) and act.deadline == send.deadline and act.size == len(reply) - 3
    act = tx.receive(reply[3:5], 0.002)
    assert isinstance(act, Wait) and act.size == len(reply) - 5
    assert tx.receive(reply[5:], 0.003) == Done(b"\x05\x06")


def test_no_reply_retries_with_the_preamble_then_fails() -> None:
    s = Session(timeout=0.05, retries=1, check="none")
    s.attach("p", 115200)  # above 28,800 baud: wake-up preamble after open and after a miss
    tx = s.read(2, 7)
    first = tx.start(0.0)
    assert isinstance(first, Send) and first.wire.startswith(codec.WAKE_UP_PREAMBLE)
    early = tx.expire(first.deadline - 0.001)  # a timer that fired early: wait on
    assert isinstance(early, Wait) and early.deadline == first.deadline
    again = tx.expire(first.deadline)
    assert isinstance(again, Send) and again.wire == codec.WAKE_UP_PREAMBLE + codec.encode_read_request(2, 7, 1)
    assert s.stats.retries == 1 and s.stats.no_response == 1
    last = tx.expire(again.deadline + 1)
    assert isinstance(last, Fail) and isinstance(last.error, NoResponseError)
    assert s.stats == MasterStats(transactions=1, retries=1, no_response=2)
    # the next transaction after a miss starts with the preamble again
    assert s.read(2, 7).start(10.0).wire.startswith(codec.WAKE_UP_PREAMBLE)


def test_bad_check_byte_is_a_frame_error_and_retried() -> None:
    s = session(retries=1)
    tx = s.read(4, 8)
    tx.start(0.0)
    reply = bytearray(codec.encode_read_response(8, b"\x01"))
    reply[-1] ^= 0xFF
    act = tx.receive(bytes(reply), 0.001)
    assert isinstance(act, Send) and s.stats.frame_errors == 1 and s.stats.retries == 1
    act = tx.receive(bytes(reply), 0.002)
    assert isinstance(act, Fail) and isinstance(act.error, CheckByteError)


def test_echo_and_foreign_frames_are_ignored() -> None:
    s = session()
    tx = s.read(5, 9)
    send = tx.start(0.0)
    reply = codec.encode_read_response(9, b"\x2a")
    # our own request echoed, then the reply, in one chunk
    assert tx.receive(send.wire + reply, 0.001) == Done(b"\x2a")
    assert s.stats.ignored_frames == 1


def test_garbage_shortens_the_wait() -> None:
    s = session()
    tx = s.read(5, 9)
    send = tx.start(0.0)
    act = tx.receive(b"\x00" * 8, 0.001)  # a whole reply's worth of bytes and no reply
    assert isinstance(act, Wait) and act.deadline < send.deadline
    act = tx.expire(act.deadline)
    assert isinstance(act, Fail) and "garbled" in str(act.error) and s.stats.frame_errors == 1


def test_handshake_check_follows_the_read() -> None:
    s = session(check="handshake")
    tx = s.read(6, 8)
    tx.start(0.0)
    reply = codec.encode_read_response(8, b"\x07")
    act = tx.receive(reply, 0.001)
    assert isinstance(act, Send) and act.wire == codec.encode_handshake_request(6)
    assert tx.receive(codec.encode_handshake_response(reply[-1]), 0.002) == Done(b"\x07")


def test_handshake_mismatch_counts_and_retries() -> None:
    s = session(check="handshake", retries=1)
    tx = s.read(6, 8)
    tx.start(0.0)
    reply = codec.encode_read_response(8, b"\x07")
    tx.receive(reply, 0.001)
    act = tx.receive(codec.encode_handshake_response(reply[-1] ^ 1), 0.002)
    assert isinstance(act, Send) and act.wire == codec.encode_read_request(6, 8, 1)  # the whole read again
    assert s.stats.check_mismatches == 1 and s.stats.retries == 1
    tx.receive(reply, 0.003)
    act = tx.receive(codec.encode_handshake_response(0), 0.004)
    assert isinstance(act, Fail) and isinstance(act.error, HandshakeMismatchError)


def test_refused_write_is_told_apart_by_the_unchanged_check_byte() -> None:
    s = session(check="handshake")
    s.device_check[7] = 0x11  # the byte the device holds before the write
    tx = s.write(7, 8, b"\x01")
    send = tx.start(0.0)
    assert send.size == 0 and send.wire == codec.encode_write(7, 8, b"\x01")
    act = tx.written(0.001)
    assert isinstance(act, Send) and act.wire == codec.encode_handshake_request(7)
    act = tx.receive(codec.encode_handshake_response(0x11), 0.002)
    assert isinstance(act, Fail) and isinstance(act.error, WriteRefusedError)


def test_broadcast_write_sends_once_and_never_waits() -> None:
    s = session(check="handshake", retries=5)
    tx = s.write(codec.BROADCAST, 8, [1, 2])
    send = tx.start(0.0)
    assert send.size == 0
    assert tx.written(0.0) == Done(None)


def test_set_guard_moves_the_check_byte_first() -> None:
    s = session(check="handshake")
    frame = codec.encode_set(3, codec.SetCommand.SAVE_EEPROM)
    s.device_check[3] = frame[-1]  # the device already holds the Set's MDOC
    tx = s.set(3, "save_eeprom")
    act = tx.start(0.0)
    assert act.wire == codec.encode_read_request(3, 1, 1)  # the guard read
    act = tx.receive(codec.encode_read_response(1, b"\x00"), 0.001)
    assert act.wire == frame and act.size == 0
    act = tx.written(0.002)
    assert act.wire == codec.encode_handshake_request(3)
    assert tx.receive(codec.encode_handshake_response(frame[-1]), 0.003) == Done(None)


def test_scan_probe_reprobes_after_a_late_reply() -> None:
    s = session()
    tx = s.probe(4)
    first = tx.start(0.0)
    act = tx.receive(codec.encode_read_response(7, b"\x03"), 0.001)  # ID 3's late reply
    assert isinstance(act, Send) and act.wire == first.wire and s.stats.ignored_frames == 1
    assert tx.receive(codec.encode_read_response(7, b"\x04"), 0.002) == Done(4)


def test_stats_is_a_frozen_snapshot() -> None:
    s = session()
    snap = s.stats
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.retries = 5  # type: ignore[misc]
    tx = s.read(1, 1)
    tx.start(0.0)
    assert snap.transactions == 0 and s.stats.transactions == 1


def test_misuse_raises_the_package_error() -> None:
    s = session()
    tx = s.read(1, 1)
    with pytest.raises(G485ValueError):
        tx.receive(b"\x01", 0.0)  # before start
    with pytest.raises(G485ValueError):
        tx.start("now")  # type: ignore[arg-type]
    with pytest.raises(G485ValueError):
        tx.start(float("nan"))
    tx.start(0.0)
    assert isinstance(tx.receive(codec.encode_read_response(1, b"\x01"), 0.0), Done)
    with pytest.raises(G485ValueError):
        tx.written(0.0)  # already over
    with pytest.raises(G485ValueError):
        Session(timeout=0)
    with pytest.raises(G485ValueError):
        s.read(1, 1, retries=-1)


def test_timeout_bound_is_the_packages() -> None:
    from fap_py._validate import MAX_TIMEOUT

    assert Session(timeout=7200).timeout == 7200.0  # was refused above 3,600 s
    with pytest.raises(G485ValueError):
        Session(timeout=MAX_TIMEOUT * 2)


def test_check_reread_reads_twice() -> None:
    s = session(check=Check.REREAD)
    tx = s.read(2, 8)
    tx.start(0.0)
    reply = codec.encode_read_response(8, b"\x09")
    act = tx.receive(reply, 0.001)
    assert isinstance(act, Send) and act.wire == codec.encode_read_request(2, 8, 1)
    assert tx.receive(reply, 0.002) == Done(b"\x09")
