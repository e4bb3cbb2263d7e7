#!/usr/bin/env python3
"""Fuzz the G485 streaming parser (fap_py/g485/codec.py).

Properties checked on every input:
  * the packets found are the same whether the bytes are fed whole, in
    random chunks, or one byte at a time (discards may be grouped
    differently, packets may not);
  * every packet's check byte matches, ``decode_frame(raw)`` gives the same
    packet, and re-encoding its fields gives ``raw`` back (encode then
    decode is the identity);
  * nothing is lost or invented: the bytes of the packets and discards,
    plus what the parser still holds (expired at the end), add up to the
    input.

    g485_fuzz.py --seconds N [--corpus DIR] [--seed S] [--json]

A mutation fuzzer (bit flips, byte inserts/deletes, splices of corpus
inputs and of valid frames); deterministic for a given --seed. The pytest
module test_g485_fuzz.py runs the same check() under hypothesis.
"""
import argparse
import json
import pathlib
import random
import sys
import time
from typing import List

from fap_py.g485 import codec


def _packets(events: List[codec.Event]) -> List[bytes]:
    return [e.raw for e in events if isinstance(e, codec.Packet)]


def _consumed(events: List[codec.Event]) -> int:
    """Input bytes the events account for (a BAD_CHECK candidate is
    reported whole but only its first byte is dropped: the search resumes
    at its second byte)."""
    n = 0
    for e in events:
        if isinstance(e, codec.Packet):
            n += len(e.raw)
        elif e.issue is codec.ParseIssue.BAD_CHECK:
            n += 1
        else:
            n += len(e.data)
    return n


def check(data: bytes, chunk_seed: int = 0) -> int:
    """Run every property on one input; return the number of packets found."""
    whole = codec.Parser()
    ev_whole = whole.feed(data) + whole.expire()
    rnd = random.Random(chunk_seed)
    chunked = codec.Parser()
    ev_chunked: List[codec.Event] = []
    pos = 0
    while pos < len(data):
        n = rnd.randint(1, 40)
        ev_chunked += chunked.feed(data[pos:pos + n])
        pos += n
    ev_chunked += chunked.expire()
    single = codec.Parser()
    ev_single: List[codec.Event] = []
    for b in data:
        ev_single += single.feed(bytes((b,)))
    ev_single += single.expire()
    pk = _packets(ev_whole)
    assert pk == _packets(ev_chunked), ("chunked", data.hex())
    assert pk == _packets(ev_single), ("byte-wise", data.hex())
    for e in ev_whole:
        if isinstance(e, codec.Packet):
            assert codec.check_byte(e.raw[2:-1]) == e.raw[-1]
            assert codec.decode_frame(e.raw) == e
            assert codec.frame(e.raw[2], e.pid, e.data) == e.raw
    assert _consumed(ev_whole) == len(data), ("accounting", data.hex())
    assert whole.buffered == 0
    return len(pk)


def _valid_frames() -> List[bytes]:
    return [codec.encode_write(1, 13, b"\x32" * 10), codec.encode_read_request(5, 1, 7),
            codec.encode_read_response(1, b"\x01\x02\x03"), codec.encode_handshake_request(9),
            codec.encode_handshake_response(0xAB), codec.encode_error_word_request(3),
            codec.encode_error_word_response(0x1234), codec.encode_set(0, 0x74)]


def mutate(rnd: random.Random, data: bytes, pool: List[bytes]) -> bytes:
    b = bytearray(data)
    for _ in range(rnd.randint(1, 4)):
        op = rnd.randrange(6)
        if op == 0 and b:
            i = rnd.randrange(len(b))
            b[i] ^= 1 << rnd.randrange(8)
        elif op == 1:
            b.insert(rnd.randint(0, len(b)), rnd.choice((0xFF, 0x00, rnd.randrange(256))))
        elif op == 2 and b:
            del b[rnd.randrange(len(b))]
        elif op == 3:
            b[rnd.randint(0, len(b)):rnd.randint(0, len(b))] = rnd.choice(pool)
        elif op == 4 and b:
            i = rnd.randrange(len(b))
            b[i] = rnd.randrange(256)
        else:
            b += rnd.choice(pool)
    return bytes(b[:600])


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="run time (default: %(default)s)")
    ap.add_argument("--corpus", type=pathlib.Path, help="seed inputs (files), e.g. build-fuzz/corpus/g485")
    ap.add_argument("--seed", type=int, default=1, help="random seed (default: %(default)s)")
    ap.add_argument("--json", action="store_true", help="one JSON line of results")
    a = ap.parse_args(argv)
    pool = _valid_frames()
    if a.corpus and a.corpus.is_dir():
        pool += [p.read_bytes() for p in sorted(a.corpus.iterdir()) if p.is_file()]
    rnd = random.Random(a.seed)
    corpus = list(pool)
    execs = packets = 0
    end = time.monotonic() + a.seconds
    while time.monotonic() < end:
        data = mutate(rnd, rnd.choice(corpus), pool)
        found = check(data, execs)
        execs += 1
        packets += found
        if found and len(corpus) < 5000 and rnd.random() < 0.05:
            corpus.append(data)
    res = {"target": "g485", "executions": execs, "packets": packets, "seconds": a.seconds}
    print(json.dumps(res) if a.json else
          f"g485_fuzz: {execs} executions, {packets} packets found, no property failed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
