"""The ring between a source and the browsers (fap_py.web._hub): it wraps, a reader that
fell behind gets its loss counted once, windows by seq and time, several readers."""
from __future__ import annotations

from fap_py.execasync import encode
from fap_py.monitor import Monitor
from fap_py.web._hub import Hub


def records(n: int, t0: float = 0.0):
    mon = Monitor("exec", 115200)
    wire = b"".join(encode(1 + i % 3, bytes([i & 0xFF]), 1 + i % 255) for i in range(n))
    return mon.feed(wire, t0, 1e-4)


def test_ring_wraps_counts_drops_and_windows() -> None:
    hub = Hub(10)
    a, b = hub.connect(backlog=0), hub.connect(backlog=0)
    hub.publish(records(4))
    got, dropped = hub.read(a, 100)
    assert [e.seq for e in got] == [1, 2, 3, 4] and dropped == 0
    hub.publish(records(21))                      # seq 5..25: the ring holds 16..25
    got, dropped = hub.read(a, 3)
    assert [e.seq for e in got] == [16, 17, 18] and dropped == 11 and a.dropped == 11
    got, dropped = hub.read(a, 100)
    assert [e.seq for e in got] == list(range(19, 26)) and dropped == 0
    got, dropped = hub.read(b, 100)               # the other reader: its own loss
    assert [e.seq for e in got] == list(range(16, 26)) and dropped == 15
    assert hub.read(a, 100) == ([], 0)
    assert hub.dropped_total == 26
    assert [e.seq for e in hub.window(seq0=20, seq1=22)] == [20, 21, 22]
    assert [e.seq for e in hub.window()] == list(range(16, 26))
    t = hub.window()[3].rec.t
    assert all(e.rec.t <= t for e in hub.window(t1=t)) and len(hub.window(t1=t)) == 4
    c = hub.connect(backlog=5)
    assert [e.seq for e in hub.read(c, 100)[0]] == list(range(21, 26))
    snap = hub.snapshot()
    assert snap["totals"]["seq"] == 25 and snap["totals"]["ring_first"] == 16
    assert sum(n["frames"] for n in snap["nodes"]) == 25


def test_several_browsers_each_get_every_frame() -> None:
    """Three streams at once over a real server: each gets all 5000 frames, in order."""
    import threading

    import pytest

    pytest.importorskip("aiohttp")
    from web_helpers import SSE

    from fap_py.web import Source, WebServer

    class Burst(Source):
        kind = "test"

        def __init__(self) -> None:
            super().__init__("exec", 115200)
            self.go = threading.Event()

        def run(self, hub, stop) -> None:
            self.go.wait(15)
            for k in range(5):
                hub.publish(records(1000, float(k)))

    src = Burst()
    with WebServer(src, port=0) as srv:
        srv.start()
        streams = [SSE("127.0.0.1", srv.port, "/api/stream?backlog=0") for _ in range(3)]
        src.go.set()
        try:
            for s in streams:
                seqs = []
                for kind, data in s.events():
                    assert kind != "dropped", data
                    if kind == "frames":
                        seqs += [e["seq"] for e in data]
                    if len(seqs) >= 5000:
                        break
                assert seqs == list(range(1, 5001))
        finally:
            for s in streams:
                s.close()


def test_an_early_expiry_is_taken_back_by_the_answer_or_a_bad_frame() -> None:
    """expire() runs on the hub's clock (when it read a frame), not the wire's: a reader
    that fell behind a second between a request and its answer must not leave a timeout.
    After the take-back the table is the one the records alone give (a recording's)."""
    from fap_py.web._nodes import Annotator, NodeTable

    mon = Monitor("exec", 115200)
    req, ans = encode(5, b"\x01\x02", 7), encode(5, b"\xaa\x55", 7)
    bad = bytearray(encode(5, b"\xaa\x55", 8))
    bad[-1] ^= 0xFF
    other = encode(1, b"\x01", 9)

    def table(frames, expire_after):
        """Feed ``frames``; expire() (wall + 2 s) after the indexes in ``expire_after``."""
        ann, tab = Annotator(), NodeTable(115200)
        for i, raw in enumerate(frames):
            for rec in mon.feed(raw, float(i), 1e-4):
                tab.add(rec, *ann.annotate(rec), wall=float(i))
            if i in expire_after:
                tab.expire(i + 2.0)
        tab.finish()                      # the end: as a recording's
        return {r["node"]: (r["requests"], r["replies"], r["timeouts"], r["errors"]) for r in tab.table()}

    for frames in ([req, ans, other], [req, other, req, ans], [req, bytes(bad), other]):
        assert table(frames, {0, 2}) == table(frames, set()), frames
    assert table([req, ans, other], {0})["5"] == (1, 1, 0, 0)
    assert table([req, other], {0})["5"] == (1, 0, 1, 0)           # really unanswered
    assert table([req, bytes(bad), other], {0})["5"] == (1, 0, 0, 1)
