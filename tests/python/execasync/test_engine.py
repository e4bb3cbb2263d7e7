"""Master and 3 slaves on the virtual bus, from Python."""
from __future__ import annotations

import threading
from typing import List

import pytest
import serial

from fap_py.errors import FapTimeoutError, InvalidValueError
from fap_py.execasync import (
    BROADCAST,
    RS485,
    Decoder,
    ExecValueError,
    Master,
    NoReplyError,
    Request,
    RS485Mode,
    ServeResult,
    Slave,
    encode,
)
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)   # ptys have no RS-485 ioctls


def test_poll_every_slave_seq_per_node(net) -> None:
    for rnd in range(3):
        for node in (1, 2, 3):
            assert net.master.next_seq(node) == rnd
            assert net.master.transact(node, b"hi\x10") == bytes([node, rnd + 1]) + b"hi\x10"
    frames = net.spy_frames()
    assert len(frames) == 18
    for req, rep in zip(frames[::2], frames[1::2]):
        assert req.ok and rep.ok and (req.node, req.seq) == (rep.node, rep.seq)
    assert [f.seq for f in frames[::2]] == [0, 0, 0, 1, 1, 1, 2, 2, 2]


def test_dropped_reply_is_resent_not_reprocessed(net) -> None:
    assert net.master.transact(2, b"start") == bytes([2, 1]) + b"start"   # seq 0
    net.master.set_timeout(0.1)               # one lost reply costs one timeout
    expected = bytes([2, 2]) + b"once"
    net.bus.drop_next(2, len(encode(2, expected, net.master.next_seq(2))))
    assert net.master.transact(2, b"once") == expected    # the original reply
    assert net.counters[2].applied == 2                    # "once" applied exactly once
    st = net.slaves[2].stats
    assert st.processed == 2 and st.resent >= 1
    m = net.master.stats
    assert m.retries >= 1 and m.timeouts >= 1 and m.replies == 2


def test_retried_seq_zero_is_processed_again(net) -> None:
    """The settled rule: 0 means start-up and is always processed, retry or not."""
    net.master.set_timeout(0.3)
    expected = bytes([2, 1]) + b"boot"
    net.bus.drop_next(2, len(encode(2, expected, 0)))
    assert net.master.transact(2, b"boot") == bytes([2, 2]) + b"boot"
    assert net.counters[2].applied == 2


def _fake_slave(port: serial.Serial, seqs: List[int]) -> None:
    """Node 9 on the raw port: first reply damaged in one data bit, then good."""
    dec = Decoder()
    while len(seqs) < 2:
        chunk = port.read(1)          # pyserial waits for all it is asked for
        if not chunk:
            return
        chunk += port.read(port.in_waiting)
        for f in dec.feed(chunk):
            if f.ok and f.node == 9:
                seqs.append(f.seq)
                frame = bytearray(encode(9, b"ok", f.seq))
                if len(seqs) == 1:
                    frame[4] ^= 0x01
                port.write(bytes(frame))


def test_corrupt_reply_caught_by_crc(net) -> None:
    seqs: List[int] = []
    t = threading.Thread(target=_fake_slave, args=(net.raw, seqs))
    t.start()
    try:
        assert net.master.transact(9, b"x") == b"ok"
    finally:
        t.join()
    assert seqs == [0, 0]                     # the retry kept its sequence number
    assert net.master.stats.corrupt == 1


def test_corrupt_request_ignored_by_slave(net) -> None:
    frame = bytearray(encode(1, b"bad", 7))
    frame[5] ^= 0x40
    net.raw.write(bytes(frame))
    (seen,) = net.spy_frames()                # relayed to every port by now
    assert not seen.ok
    assert net.master.transact(1, b"good") == bytes([1, 1]) + b"good"
    assert net.counters[1].applied == 1
    assert net.slaves[1].stats.corrupt == 1


def test_bit_errors_on_the_wire_are_survived(net) -> None:
    net.master.transact(3, b"a")              # seq 0 done: later retries are resends
    net.master.set_timeout(0.1)
    net.bus.corrupt_next(0, 3)                # the master's next request is hit
    assert net.master.transact(3, b"z") == bytes([3, 2]) + b"z"
    assert net.counters[3].applied == 2
    assert net.master.stats.retries >= 1


def test_broadcast_reaches_all_nobody_answers(net) -> None:
    net.master.broadcast(b"\xb0\x10")
    for c in net.counters.values():
        assert c.broadcast_seen.wait(3)
        assert c.broadcasts == [b"\xb0\x10"]
    for node in (1, 2, 3):                    # each slave is past the broadcast
        net.master.transact(node, b"after")
    frames = net.spy_frames()
    assert frames[0].node == BROADCAST and frames[0].data == b"\xb0\x10"
    assert len(frames) == 7                   # then request/reply pairs only
    assert all(s.stats.replies == 1 for s in net.slaves.values())


def test_absent_node_raises_no_reply(net) -> None:
    net.master.set_timeout(0.005, retries=1)
    with pytest.raises(NoReplyError) as info:
        net.master.transact(77, b"?")
    assert isinstance(info.value, FapTimeoutError) and isinstance(info.value, TimeoutError)
    assert net.master.stats.timeouts == 2
    assert net.master.next_seq(77) == 0  # a failed transaction restarts the node at 0


def test_bad_arguments(net) -> None:
    for node in (0, 255, 300):
        with pytest.raises(ExecValueError):
            net.master.transact(node, b"")
    with pytest.raises(InvalidValueError):
        net.master.transact(1, b"x" * 256)
    with pytest.raises(ValueError):
        Slave(net.bus.paths[4], node=0, handler=lambda r: b"")
    with pytest.raises(OSError):
        Master("/nonexistent/tty")


def test_serve_on_callers_thread_and_handler_errors() -> None:
    seen: List[Request] = []

    def handler(req: Request) -> bytes:
        seen.append(req)
        if req.data == b"boom":
            raise RuntimeError("handler failed")
        return req.data.upper()

    with VirtualBus(ports=2) as bus, \
            Slave(bus.paths[1], node=5, handler=handler, rs485=LINE) as slave, \
            Master(bus.paths[0], timeout=2.0, retries=0, rs485=LINE) as master:
        assert slave.serve(0.001) is ServeResult.TIMEOUT
        result: List[object] = []
        t = threading.Thread(target=lambda: result.append(master.transact(5, b"abc")))
        t.start()
        assert slave.serve(2) is ServeResult.PROCESSED
        t.join()
        assert result == [b"ABC"]
        master.set_timeout(0.1)                  # "boom" is never answered
        errors: List[BaseException] = []

        def failing_call() -> None:
            try:
                master.transact(5, b"boom")
            except NoReplyError as exc:   # the handler failed: no reply
                errors.append(exc)

        t = threading.Thread(target=failing_call)
        t.start()
        with pytest.raises(RuntimeError, match="handler failed"):
            slave.serve(2)
        t.join()
        assert len(errors) == 1
        assert [r.data for r in seen] == [b"abc", b"boom"]
        assert slave.stats.processed == 2 and slave.stats.no_reply == 1
    assert slave.closed and master.closed


def test_two_wire_bus_with_echo_suppression() -> None:
    """A bus that echoes every byte back: echo suppression keeps nodes sane."""
    line = RS485(mode=RS485Mode.NONE, echo_suppression=True)
    with VirtualBus(ports=3, echo=True) as bus, \
            Slave(bus.paths[1], node=1, handler=lambda r: r.data[::-1], rs485=line).start() as s1, \
            Slave(bus.paths[2], node=2, handler=lambda r: r.data * 2, rs485=line).start() as s2, \
            Master(bus.paths[0], timeout=0.1, rs485=line) as master:
        for _ in range(5):
            assert master.transact(1, b"abc") == b"cba"
            assert master.transact(2, b"xy") == b"xyxy"
        assert s1.stats.processed == 5 and s2.stats.processed == 5
        assert master.stats.retries == 0 and master.stats.unexpected == 0


def test_vanished_port_raises_port_error() -> None:
    with VirtualBus(ports=2) as bus, \
            Slave(bus.paths[1], node=1, handler=lambda r: r.data, rs485=LINE) as slave, \
            Master(bus.paths[0], timeout=0.05, rs485=LINE) as master:
        bus.disconnect(1, 0.3)
        bus.disconnect(0, 0.3)
        with pytest.raises(OSError):
            slave.serve(5)
        with pytest.raises(OSError):
            master.transact(1, b"x")


def _reopen_when_back(node: "Master | Slave", within: float = 5.0) -> None:
    """Reopen ``node`` once the bus has brought its port back. Nothing can be
    waited on for a path that reappears, so this retries on a bounded clock."""
    import time

    deadline = time.monotonic() + within
    while True:
        try:
            node.reopen()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.01)


def test_reopen_after_the_port_comes_back() -> None:
    with VirtualBus(ports=2) as bus, \
            Slave(bus.paths[1], node=1, handler=lambda r: r.data[::-1], rs485=LINE) as slave, \
            Master(bus.paths[0], timeout=0.5, rs485=LINE) as master:
        bus.disconnect(0, 0.05)
        bus.disconnect(1, 0.05)
        with pytest.raises(OSError):
            master.transact(1, b"x")
        with pytest.raises(OSError):
            slave.serve(5)
        _reopen_when_back(master)
        _reopen_when_back(slave)
        result: List[bytes] = []
        t = threading.Thread(target=lambda: result.append(master.transact(1, b"abc")))
        t.start()
        assert slave.serve(5) is ServeResult.PROCESSED
        t.join(5)
        assert result == [b"cba"]


def test_broadcast_then_transact_at_once_keeps_the_broadcast(net) -> None:
    """The transaction's discard of stale input must not discard the
    broadcast still in our output queue (it once did: tcflush(TCIOFLUSH))."""
    for i in range(10):
        net.master.broadcast(bytes([i]))
        assert net.master.transact(2, b"t") == bytes([2, i + 1]) + b"t"
    for node in (1, 3):   # a slave handles frames in order: its reply means it saw them all
        assert net.master.transact(node, b"t") == bytes([node, 1]) + b"t"
    for c in net.counters.values():
        assert c.broadcasts == [bytes([i]) for i in range(10)], (c.node, c.broadcasts)
