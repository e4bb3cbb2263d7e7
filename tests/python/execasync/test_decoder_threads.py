"""Issue 32 item 19: one Decoder fed from two threads at once (real threads).

Before the fix the C decoder state was shared without a lock (execAsyncByteIn
releases the GIL), and a feed raised ``ValueError: 0 is not a valid Status``.
Now each feed() holds the decoder's lock: a call decodes its bytes as one run."""
from __future__ import annotations

import threading
from typing import List

from fap_py.execasync import Decoder, Status, encode

FRAMES_PER_FEED = 20
FEEDS = 150


def _feeders(dec: Decoder, chunk: bytes, n_threads: int) -> "tuple[List[int], List[str]]":
    counts = [0] * n_threads
    errors: List[str] = []
    start = threading.Barrier(n_threads)

    def run(k: int) -> None:
        start.wait()
        try:
            for _ in range(FEEDS):
                frames = dec.feed(chunk)
                assert all(f.status is Status.GOOD and f.node == 5 for f in frames), frames
                counts[k] += len(frames)
        except Exception as exc:
            errors.append(f"{type(exc).__name__}: {exc}")

    threads = [threading.Thread(target=run, args=(k,)) for k in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in threads)
    return counts, errors


def test_two_threads_feeding_one_decoder() -> None:
    chunk = encode(5, bytes(range(200)), 1) * FRAMES_PER_FEED     # whole frames per call
    counts, errors = _feeders(Decoder(), chunk, 2)
    assert errors == []
    assert counts == [FEEDS * FRAMES_PER_FEED] * 2   # every frame of every call, all GOOD


def test_reset_while_another_thread_feeds() -> None:
    dec = Decoder()
    chunk = encode(5, b"x" * 100, 2) * FRAMES_PER_FEED
    stop = threading.Event()

    def resetter() -> None:
        while not stop.is_set():
            dec.reset()

    t = threading.Thread(target=resetter)
    t.start()
    try:
        counts, errors = _feeders(dec, chunk, 1)
    finally:
        stop.set()
        t.join()
    assert errors == []
    assert counts[0] == FEEDS * FRAMES_PER_FEED     # a reset between calls loses nothing
