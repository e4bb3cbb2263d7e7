"""Frames arriving in pieces (a paced line): the fast paths that hold the first bytes
unparsed must decide exactly what the Parser decides."""
from __future__ import annotations

import os
import random
import select
import time
from typing import Callable, List

import pytest

from fap_py.g485 import Discarded, ParseIssue, Parser, SimDevice, Simulator, codec
from fap_py.g485.errors import G485ValueError
from fap_py.g485.transaction import Done, Session, Wait

DEADLINE = 5.0


def _frames(vectors: List[dict]) -> List[bytes]:
    return [bytes.fromhex(v["frame"]) for v in vectors]


def _until(cond: Callable[[], bool], what: str) -> None:
    end = time.monotonic() + DEADLINE
    while not cond():
        assert time.monotonic() < end, what
        time.sleep(0.001)


def test_frame_start_holds_only_what_the_parser_holds_silently(vectors) -> None:
    rng = random.Random(485)
    chunks = []
    for f in _frames(vectors):
        chunks += [f[:k] for k in range(len(f) + 1)]
        chunks += [codec.WAKE_UP_PREAMBLE + f[:3], b"\xff\xff\xfe\x02", b"\xff\xff\x02\x01", b"\xff\xff\x02\xff"]
        chunks += [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 8))) for _ in range(5)]
    held = 0
    for chunk in chunks:
        if codec.frame_start(chunk):
            held += 1
            p = Parser()
            assert p.feed(chunk) == [] and p.buffered == len(chunk), chunk.hex(" ")
            assert codec.exact_packet(chunk) is None
    assert held > len(vectors)  # every frame's first pieces were held
    assert codec.frame_start(bytearray(b"\xff\xff")) == codec.frame_start(b"\xff\xff")  # bytes-like
    for bad in (None, 300, "ffff"):   # anything else is named, like every codec call
        with pytest.raises(G485ValueError):
            codec.frame_start(bad)


def test_reply_in_pieces_is_the_same_however_it_is_cut() -> None:
    reply = codec.encode_read_response(1, bytes(range(10)))
    for cut in range(1, len(reply)):
        for first, rest in ((reply[:cut], reply[cut:]), (reply[:cut], reply[cut:] + b"\x00")):
            s = Session(check="none")
            s.attach("p", 1000000)
            tx = s.read(1, 1, 10)
            tx.start(0.0)
            act = tx.receive(first, 0.001)
            assert isinstance(act, Wait) and act.size == len(reply) - cut  # never past the reply
            got = tx.receive(rest, 0.002)
            if rest == reply[cut:]:
                assert got == Done(bytes(range(10)))
            else:  # a byte too many after the reply: the Parser's verdict, as before
                assert isinstance(got, Done) and got.value == bytes(range(10))
            assert s.stats.frame_errors == 0


class _Recording(SimDevice):
    def __init__(self, address: int) -> None:
        super().__init__(address)
        self.seen: list = []

    def handle(self, event):  # type: ignore[no-untyped-def]
        self.seen.append(event)
        return super().handle(event)


def test_simulator_answers_a_request_written_in_pieces(pty_link) -> None:
    path, fd = pty_link
    dev = _Recording(4)
    request = codec.encode_read_request(4, 7, 1)
    sim = Simulator(path, [dev], idle_timeout=5.0)
    got: List[bytes] = []
    read = sim._io.read_nowait

    def recording_read(n: int) -> bytes:
        chunk = read(n)
        got.append(chunk)
        return chunk

    sim._io.read_nowait = recording_read  # type: ignore[method-assign]  # before the thread binds it
    with sim:
        for cut in (1, 2, 3, 4, 5):
            del got[:]
            os.write(fd, request[:cut])
            _until(lambda: b"".join(got) == request[:cut], "the simulator reads the first piece")
            assert not select.select([fd], [], [], 0)[0]  # no reply to a partial request
            os.write(fd, request[cut:])
            _until(lambda: select.select([fd], [], [], 0)[0] != [], "the reply")
            reply = b""
            while len(reply) < 7:
                _until(lambda: select.select([fd], [], [], 0)[0] != [], "the rest of the reply")
                reply += os.read(fd, 64)
            assert reply == codec.encode_read_response(7, b"\x04")
        assert sim.error is None and sim.replies_sent == 5
    assert [e.raw for e in dev.seen] == [request] * 5


def test_simulator_drops_an_unfinished_request_after_the_idle_time(pty_link) -> None:
    path, fd = pty_link
    dev = _Recording(4)
    request = codec.encode_read_request(4, 7, 1)
    with Simulator(path, [dev], idle_timeout=0.02) as sim:
        os.write(fd, request[:4])
        _until(lambda: sim.events >= 1, "the held bytes expire")
        assert isinstance(dev.seen[0], Discarded) and dev.seen[0].issue is ParseIssue.STALE
        assert sim.replies_sent == 0
        os.write(fd, request)  # a whole request afterwards is answered
        _until(lambda: sim.replies_sent == 1, "the reply")
        assert sim.error is None
