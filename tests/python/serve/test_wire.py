"""The framing's stream reader alone (fap_py.serve._wire.MessageReader): it reads in
chunks, so messages that share a chunk, a message split across chunks, and the
deadline of a started message are its own rules, checked here without a daemon."""
from __future__ import annotations

import asyncio

import pytest

from fap_py.serve._errors import ProtocolError
from fap_py.serve._wire import MessageReader, pack


def _reader(*chunks: bytes, eof: bool = True) -> asyncio.StreamReader:
    r = asyncio.StreamReader()
    for c in chunks:
        r.feed_data(c)
    if eof:
        r.feed_eof()
    return r


def test_messages_in_one_chunk_and_across_chunks_come_whole_and_in_order():
    async def main() -> list:
        a, b, c = pack({"op": "a"}), pack({"op": "b", "data": "00" * 300}), pack({"op": "c"})
        blob = a + b + c
        m = MessageReader(_reader(blob[:3], blob[3:len(a) + 7], blob[len(a) + 7:]), 1.0)
        return [await m.next(), await m.next(), await m.next(), await m.next()]

    got = asyncio.run(main())
    assert [x and x["op"] for x in got] == ["a", "b", "c", None]   # None: clean end
    assert got[1]["data"] == "00" * 300


def test_a_stream_cut_inside_a_message_or_a_bad_length_is_a_protocol_error():
    async def cut() -> None:
        await MessageReader(_reader(pack({"op": "a"})[:-2]), 1.0).next()

    async def bad_length() -> None:
        await MessageReader(_reader(b"\x00\x00\x00\x00{}"), 1.0).next()

    with pytest.raises(ProtocolError, match="inside a message"):
        asyncio.run(cut())
    with pytest.raises(ProtocolError, match="length 0"):
        asyncio.run(bad_length())


def test_a_started_message_must_end_within_the_body_timeout_between_messages_no_limit():
    async def half_sent() -> None:
        await MessageReader(_reader(pack({"op": "a"})[:5], eof=False), 0.05).next()

    async def idle() -> bool:
        m = MessageReader(_reader(eof=False), 0.05)
        task = asyncio.ensure_future(m.next())
        _, pending = await asyncio.wait([task], timeout=0.2)   # four body timeouts, none begun
        task.cancel()
        return task in pending

    with pytest.raises(asyncio.TimeoutError):
        asyncio.run(half_sent())
    assert asyncio.run(idle())
