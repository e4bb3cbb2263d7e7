"""Volume: real client processes share one `fap serve` on a paced virtual bus, every
protocol, both socket kinds (issue 34). Each client tags its requests with its own id
and the responder echoes the tag: every answer must be the asker's own (0 misdelivered),
the wire must show each request followed by its reply (0 interleaved, from the bus's
capture file), and the daemon's totals must agree (transactions, 0 errors, 0 late).

``FAP_SERVE_VOLUME`` is the number of transactions over all 10 cases (default 2000;
CI's soak step, .ci/soak.sh, runs 100000). Each client counts its ok, misdelivered
and timed-out transactions; the file prints the totals and the rate at the end."""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import threading
from typing import Any, Dict, Iterator, List, Tuple

import pytest
import serial
from serve_helpers import fap_echo, mikroc_echo, start_daemon

from fap_py import mikroc
from fap_py.execasync import Decoder
from fap_py.g485.codec import Packet, Parser
from fap_py.vbus import VirtualBus, read_capture

PROTOCOLS = ("exec", "mikroc", "g485", "fap", "raw")
SOCKETS = ("unix", "tcp")
CASES = len(PROTOCOLS) * len(SOCKETS)
_VOLUME = os.environ.get("FAP_SERVE_VOLUME", "2000")
if not _VOLUME.isdigit():
    raise pytest.UsageError(f"FAP_SERVE_VOLUME must be a whole number of transactions, not {_VOLUME!r}")
N_CLIENTS = 3
#: transactions of one case (at least 2 per client: a G485 client's write and read)
PER_CASE = max(2 * N_CLIENTS, int(_VOLUME) // CASES)
#: the line rate, for speed: every protocol's engine takes 1 Mbaud (mikroC's too)
BAUD = 1_000_000
#: the slowest case's rate on a loaded 2-core machine (FAP ~570/s), with a margin, and room
#: for FAP's 15 s DATA_DONE waits: the per-test timeout grows with the volume
SLOWEST_RATE = 100.0
TIMEOUT_S = 90 + PER_CASE / SLOWEST_RATE

#: (protocol, socket, transactions, seconds, the clients' timeouts + late replies, the
#: engines' timeouts) of each case run, for the summary
RESULTS: List[Tuple[str, str, int, float, int, str]] = []

CLIENT = r"""
import asyncio, json, sys, time
proto, url, cid, n = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
res = {"ok": 0, "bad": 0, "timeouts": 0, "late": 0, "transactions": 0}
def begin():                             # connected: the rate is over the clients' span
    res["start"] = time.monotonic()      # (CLOCK_MONOTONIC: one clock for all processes)
from fap_py.errors import FapTimeoutError
res["wrong"] = []                        # the first misdelivered answers: (wanted, got)
def count(want, got, k=1):
    res["ok" if want == got else "bad"] += k
    if want != got and len(res["wrong"]) < 5:
        res["wrong"].append((repr(want), repr(got)))

if proto == "exec":
    from fap_py.execasync import Master, NoReplyError
    TIMEOUTS = (NoReplyError, FapTimeoutError)
    tag = lambda i: f"{cid}:{i}".encode()
    if cid % 2:                          # one at a time
        with Master(url) as m:
            begin()
            for i in range(n):
                try:
                    count(tag(i), m.transact(5, tag(i)))
                except TIMEOUTS:
                    res["timeouts"] += 1
    else:                                # 4 in flight on one connection (asyncio)
        async def main():
            async with Master(url) as m:
                begin()
                async def one(i):
                    try:
                        count(tag(i), await m.atransact(5, tag(i)))
                    except TIMEOUTS:
                        res["timeouts"] += 1
                for k in range(0, n, 4):
                    await asyncio.gather(*[one(i) for i in range(k, min(n, k + 4))])
        asyncio.run(main())
    res["transactions"] = n
elif proto == "mikroc":
    from fap_py import mikroc
    tag = lambda i: bytes([cid, (i >> 8) & 0xFF, i & 0xFF])
    with mikroc.Master(url) as m:
        begin()
        async def main():
            async def one(i):
                try:
                    r = await m.arequest(0x12, tag(i), timeout=2.0)
                    count((0x12, tag(i)[::-1]), (r.address, r.data))
                except FapTimeoutError:
                    res["timeouts"] += 1
            for k in range(0, n, 4):
                await asyncio.gather(*[one(i) for i in range(k, min(n, k + 4))])
        if cid % 2:
            for i in range(n):
                try:
                    r = m.request(0x12, tag(i), timeout=2.0)
                    count((0x12, tag(i)[::-1]), (r.address, r.data))
                except FapTimeoutError:
                    res["timeouts"] += 1
        else:
            asyncio.run(main())
    res["transactions"] = n
elif proto == "raw":
    from fap_py.serve import Connection
    tag = lambda i: f"{cid}:{i}\n".encode()
    with Connection(url, protocol="raw") as c:
        begin()
        for k in range(0, n, 4):         # 4 outstanding: queued on the daemon
            sent = [(i, c.submit("transact", data=tag(i).hex(), terminator="0a", timeout=2.0))
                    for i in range(k, min(n, k + 4))]
            for i, a in sent:
                try:
                    count(tag(i), bytes.fromhex(a.result()["data"]))
                except FapTimeoutError:
                    res["timeouts"] += 1
    res["transactions"] = n
elif proto == "g485":
    from fap_py.g485 import G485Master, NoResponseError
    address = 3 + cid                    # each client its own device
    with G485Master(url) as m:
        begin()
        for i in range(n // 2):          # a write and a read: 2 transactions
            t = (i & 0xFFFF).to_bytes(2, "big")
            try:
                m.write(address, 10, t)
                got = m.read(address, 7, 5, check="none")  # register 7: the device's ID
                count((address, t), (got[0], got[3:]), 2)
            except (NoResponseError, FapTimeoutError):
                res["timeouts"] += 1
    res["transactions"] = 2 * (n // 2)
elif proto == "fap":
    from fap_py import Master
    slave = 3 + cid                      # each client its own slave
    tag = lambda i: f"{cid}:{i}".encode()
    missed = set()                       # tags that timed out: their echo, if it comes, is late
    with Master(url, slaves=[slave]) as m:
        m.wait_active([slave], timeout=30)
        begin()
        for i in range(n):
            m.send(tag(i), slave)
            try:
                while True:              # every slave's messages reach every client
                    msg = m.recv(timeout=40.0)   # beyond the engine's 15 s DATA_DONE wait
                    if msg.source != slave:
                        continue
                    if msg.data[::-1] in missed:
                        res["late"] += 1
                        continue
                    count(tag(i)[::-1], msg.data)
                    break
            except FapTimeoutError:
                res["timeouts"] += 1
                missed.add(tag(i))
    res["transactions"] = n
res["end"] = time.monotonic()
print(json.dumps(res))
"""


def _client(proto: str, url: str, cid: int, n: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-I", "-c", CLIENT, proto, url, str(cid), str(n)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@contextlib.contextmanager
def _line_echo(path: str, baud: int) -> Iterator[None]:
    """A raw responder: each line it hears (up to a newline) goes back unchanged."""
    stop = threading.Event()
    port = serial.Serial(path, baud, timeout=0.1)

    def serve() -> None:
        held = b""                      # a line split across read timeouts is still one line
        while not stop.is_set():
            held += port.read_until(b"\n")
            if held.endswith(b"\n"):
                port.write(held)
                held = b""

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join(5)
        port.close()


@contextlib.contextmanager
def _responders(proto: str, bus: VirtualBus) -> Iterator[Tuple[List[str], List[Any]]]:
    """The slaves of ``proto`` on the bus's ports 1..; yields the daemon's extra options
    and the FAP slaves."""
    from fap_py.execasync import RS485, RS485Mode, Slave
    from fap_py.g485 import SimDevice, Simulator

    line = RS485(mode=RS485Mode.NONE)
    slaves: List[Any] = []
    with contextlib.ExitStack() as stack:
        if proto == "exec":
            stack.enter_context(Slave(bus.paths[1], BAUD, node=5, handler=lambda r: r.data,
                                      rs485=line)).start()
            extra = ["--timeout", "2", "--retries", "0"]
        elif proto == "mikroc":
            stack.enter_context(mikroc_echo(bus.paths[1], baud=BAUD))
            extra = ["--timeout", "2"]
        elif proto == "raw":
            stack.enter_context(_line_echo(bus.paths[1], BAUD))
            extra = []
        elif proto == "g485":
            stack.enter_context(Simulator(bus.paths[1], [SimDevice(3 + c) for c in range(N_CLIENTS)],
                                          baudrate=BAUD, rs485=line))
            extra = ["--timeout", "2", "--retries", "0"]
        else:
            for c in range(N_CLIENTS):
                # byte_gap 0.1 s, not 10 ms: three slaves share this loaded process, and a
                # frame one of them reads across a pause is dropped (a 15 s DATA_DONE wait)
                slaves.append(stack.enter_context(fap_echo(bus.paths[1 + c], 3 + c, BAUD, byte_gap=0.1)))
            extra = ["--slaves", ",".join(str(3 + c) for c in range(N_CLIENTS))]
        yield extra, slaves


def _runs(cap: Any) -> List[Tuple[int, bytes]]:
    """The capture as runs: (sender port, the bytes it sent before another port spoke)."""
    runs: List[Tuple[int, bytearray]] = []
    for r in cap.records:
        if runs and runs[-1][0] == r.port:
            runs[-1][1].extend(r.data)
        else:
            runs.append((r.port, bytearray(r.data)))
    return [(p, bytes(b)) for p, b in runs]


def _one_request_one_reply(proto: str, req: bytes, rep: bytes) -> bool:
    """Whether the master's run ``req`` is one request and the next run ``rep`` its reply."""
    if proto == "exec":
        a, b = Decoder().feed(req), Decoder().feed(rep)
        return len(a) == len(b) == 1 and (a[0].node, a[0].seq, a[0].data) == (b[0].node, b[0].seq, b[0].data)
    if proto == "mikroc":
        x, y = mikroc.Decoder().feed(req), mikroc.Decoder().feed(rep)
        return len(x) == len(y) == 1 and isinstance(x[0], mikroc.Message) and isinstance(y[0], mikroc.Message) \
            and x[0].data == y[0].data[::-1]
    if proto == "raw":
        return req == rep and req.count(b"\n") == 1
    # g485: one op to one device (a write and its handshake, or a read), ended by the one reply;
    # the session's first op starts with a wake-up preamble (0xFF bytes)
    events = Parser().feed(req)
    packets = [e for e in events if isinstance(e, Packet)]
    replies = Parser().feed(rep)
    return bool(packets) and len({p.address for p in packets}) == 1 and \
        all(set(e.data) == {0xFF} for e in events if not isinstance(e, Packet)) and \
        len(replies) == 1 and isinstance(replies[0], Packet)


def _wire(proto: str, capture: str) -> Tuple[int, List[str]]:
    """The wire's transactions (a master run and the responder's run after it) and the
    ones that were not one request followed by its own reply (hex, for the message)."""
    cap = read_capture(capture)
    runs = _runs(cap)
    bad = [f"collision at {e.t_us} us" for e in cap.events_of("collision")]
    if len(runs) % 2:
        bad.append(f"{len(runs)} runs: one has no partner")
    for (mp, req), (sp, rep) in zip(runs[::2], runs[1::2]):
        if mp != 0 or sp == 0 or not _one_request_one_reply(proto, req, rep):
            bad.append(f"port {mp}: {req.hex()} then port {sp}: {rep.hex()}")
    return len(runs) // 2, bad


@pytest.mark.timeout(TIMEOUT_S)
@pytest.mark.parametrize("sock", SOCKETS)
@pytest.mark.parametrize("proto", PROTOCOLS)
def test_clients_get_their_own_answers(proto: str, sock: str, tmp_path: Any) -> None:
    capture = str(tmp_path / "bus.cap")
    ports = 1 + (N_CLIENTS if proto == "fap" else 1)
    unit = 2 if proto == "g485" else 1          # a G485 client writes and reads back: 2 each
    units = PER_CASE // unit
    share = [unit * (units // N_CLIENTS + (c < units % N_CLIENTS)) for c in range(N_CLIENTS)]
    results: List[Dict[str, Any]] = []
    with VirtualBus(ports=ports, baud=BAUD, capture=capture) as bus, \
            _responders(proto, bus) as (extra, slaves):
        listen = ["--listen", "tcp://127.0.0.1:0"] if sock == "tcp" else []
        d = start_daemon(str(tmp_path), bus.paths[0], "--baud", str(BAUD), *extra, *listen,
                         protocol=proto)
        procs: List[subprocess.Popen] = []
        try:
            urls = [u for u in d.ready["listen"] if u.startswith("fapd:///") == (sock == "unix")]
            assert len(urls) == 1, d.ready
            procs = [_client(proto, urls[0], c, share[c]) for c in range(N_CLIENTS)]
            for p in procs:
                out, err = p.communicate(timeout=TIMEOUT_S)
                assert p.returncode == 0, err
                results.append(json.loads(out))
            st = d.status()
            lost = sum(s.stats.gap_timeouts for s in slaves)   # frames a FAP slave dropped
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.communicate()
            d.stop()
    total = sum(r["transactions"] for r in results)
    counts = {k: sum(r[k] for r in results) for k in ("ok", "bad", "timeouts", "late")}
    took = max(r["end"] for r in results) - min(r["start"] for r in results)
    # the engines' own timeouts (FAP: a DATA_DONE waited out, a frame dropped on a gap) are
    # counted, not failed on: what must hold is that every client got each of its answers
    engine = {k: v for k, v in st["engine"].items() if v and ("timeout" in k or k == "no_response")}
    if lost:
        engine["slaves' gap_timeouts"] = lost
    RESULTS.append((proto, sock, total, took, counts["timeouts"] + counts["late"] + st["totals"]["late"],
                    ", ".join(f"{k} {v}" for k, v in engine.items()) or "none"))
    assert counts["bad"] == 0 and counts["late"] == 0, (counts, [r["wrong"] for r in results])  # 0 misdelivered
    assert counts["ok"] + counts["timeouts"] == total, counts
    if proto == "fap":
        # FAP can lose a frame the protocol does not resend: one a receiver drops on its byte
        # gap (seen beside a CPU hog: the virtual bus's thread stalled mid-frame, the daemon's
        # master counted gap_timeouts 1 and a client waited out its echo). Such a loss is
        # allowed when counted: every client timeout must be one the engines counted.
        assert counts["timeouts"] <= sum(engine.values()), (counts, engine)
    else:
        assert counts["timeouts"] == 0, (counts, engine)
    assert st["totals"]["transactions"] == total, st["totals"]
    assert st["totals"]["errors"] == 0 and st["totals"]["late"] == 0, st["totals"]
    if proto != "fap":          # FAP's engine polls on its own: no request/reply pairs to check
        pairs, bad = _wire(proto, capture)
        assert bad == [], bad[:10]                                            # 0 interleaved
        assert pairs == total


@pytest.fixture(scope="module", autouse=True)
def _summary(pytestconfig: Any) -> Iterator[None]:
    """After the cases: each one's transactions and rate, and the total (shown under -q)."""
    yield
    if not RESULTS:
        return
    lines = [f"fap serve volume {p:6} {k:4}: {t:7} transactions in {x:6.1f} s, {t / x:6.0f}/s, "
             f"{slow} timeouts or late; engine timeouts: {engine}" for p, k, t, x, slow, engine in RESULTS]
    n, s = sum(r[2] for r in RESULTS), sum(r[3] for r in RESULTS)
    lines.append(f"fap serve volume: {n} transactions in {len(RESULTS)} cases, {s:.1f} s of "
                 f"client time, {n / s:.0f}/s")
    out = pytestconfig.pluginmanager.get_plugin("terminalreporter")
    with pytestconfig.pluginmanager.get_plugin("capturemanager").global_and_fixture_disabled():
        out.write_line("")
        for line in lines:
            out.write_line(line)
