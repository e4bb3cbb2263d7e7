"""Hostile HTTP against ``fap web`` while a real sim bus is polled: slow header senders, huge
headers, a huge body, bad JSON to the control endpoint, many streams that never read. The
stream of a well-behaved browser keeps flowing, the API keeps answering, the source is not
slowed (its frames keep coming in at the bus's pace)."""
from __future__ import annotations

import socket
import threading
import time

import pytest
from web_helpers import SITE, SSE, WAIT_S, Poller, get_json, send, wait_until

pytest.importorskip("aiohttp")

from fap_py.web import SimSource, WebServer
from fap_py.web._server import MAX_STREAMS

SLOW = 100          # connections that send half a request line and stop


class Reader(threading.Thread):
    """A good browser: reads the stream, remembers the highest seq and when it came."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.sse = SSE("127.0.0.1", port, "/api/stream?backlog=0")
        self.seq = 0
        self.dropped = 0
        self.stop = False

    def run(self) -> None:
        try:
            for kind, data in self.sse.events():
                if kind == "frames" and data:
                    self.seq = data[-1]["seq"]
                elif kind == "dropped":
                    self.dropped = data["total"]
                if self.stop:
                    return
        except (OSError, AttributeError, ValueError):   # closed under it at the end
            pass


def _raw(port: int, data: bytes) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=WAIT_S)
    if data:
        s.sendall(data)
    return s


def _answer(s: socket.socket) -> bytes:
    """The status line of what the server answered (b'' when it just closed)."""
    buf = b""
    try:
        while b"\r\n" not in buf:
            chunk = s.recv(4096)
            if not chunk:
                break
            buf += chunk
    except OSError:
        pass
    return buf.split(b"\r\n", 1)[0]


def test_hostile_http_does_not_stall_the_stream():
    src = SimSource(SITE)
    with WebServer(src, port=0) as srv:
        srv.start()
        port = srv.port
        poller = Poller(src.describe()["master_port"])
        reader = Reader(port)
        reader.start()
        socks = []
        try:
            wait_until(lambda: reader.seq > 50, what="the good stream")
            # slow header senders: a request line and half a header, then nothing
            for _ in range(SLOW):
                socks.append(_raw(port, b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: a"))
            # streams that never read, up to the limit; one more is refused
            for _ in range(MAX_STREAMS - 1):
                socks.append(_raw(port, b"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"))
            mark, t_mark = reader.seq, time.monotonic()
            # a 100 kB header: refused with a 4xx, not read forever
            big = _raw(port, b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 100_000 + b"\r\n\r\n")
            status = _answer(big)
            assert status == b"" or status.split()[1].startswith(b"4"), status
            big.close()
            # a huge body to the control endpoint
            status, ans = send(srv.url + "api/faults", "POST", b"[" * 1_000_000)
            assert status == 413 and ans["ok"] is False
            # bad JSON, many times
            for body in (b"{", b"\xff\xfe", b"[" * 5000, b'"x"', b"null", b'{"kind": []}', b"{}") * 20:
                status, ans = send(srv.url + "api/faults", "POST", body)
                assert status == 400 and ans["ok"] is False and ans["error"], (body[:20], ans)
            # the stream limit: the next one is told so
            wait_until(lambda: get_json(srv.url + "api/stats")["totals"]["clients"] >= MAX_STREAMS,
                       what="every stream connected")
            over = _raw(port, b"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            assert b" 503 " in _answer(over) + b" "
            over.close()
            # through all of it the good browser's frames kept coming, the API answers
            wait_until(lambda: reader.seq >= mark + 200, what="the good stream after the attacks")
            t0 = time.monotonic()
            snap = get_json(srv.url + "api/stats")
            assert time.monotonic() - t0 < 2.0
            assert snap["source"]["error"] is None
            # the source was not slowed: the tap holds every frame the master exchanged
            poller.pause()
            st = poller.master.stats
            wait_until(lambda: get_json(srv.url + "api/stats")["totals"]["frames"] >= st.tx_frames + st.rx_frames,
                       what="every frame of the master in the table")
            assert st.timeouts == 0 and st.replies == st.transactions
            assert time.monotonic() - t_mark < 15
        finally:
            for s in socks:
                s.close()
            reader.stop = True
            reader.sse.close()
            reader.join(WAIT_S)
            poller.close()
        # the stuck streams' slots come back once their sockets are gone
        wait_until(lambda: get_json(srv.url + "api/stats")["totals"]["clients"] <= 1, what="slots freed")
        assert src.sim.faults_list() == []
