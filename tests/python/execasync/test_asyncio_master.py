"""Exec async master in an asyncio loop (Master.atransact): the C engine's
non-blocking steps driven by loop.add_reader and loop timers, no thread.
The slaves are the real engine, served in their own threads (conftest)."""
from __future__ import annotations

import asyncio
import logging
import threading
from typing import Any, List, Tuple

import pytest

from fap_py.errors import ClosedError
from fap_py.execasync import RS485, ExecAsyncError, Master, NoReplyError, Request, RS485Mode, Slave, encode
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)   # ptys have no RS-485 ioctls
Net = Any                           # conftest's Net (the `net` fixture)


class Counter:
    """A slave handler that counts what it applied (node, count, data)."""

    def __init__(self, node: int) -> None:
        self.node = node
        self.applied = 0
        self.lock = threading.Lock()

    def handler(self, req: Request) -> bytes:
        with self.lock:
            self.applied += 1
            return bytes([self.node, self.applied]) + req.data


def test_atransact_polls_each_slave_without_a_thread(net: Net) -> None:
    async def main() -> List[bytes]:
        threads = threading.active_count()
        replies = []
        for rnd in range(3):
            for node in (1, 2, 3):
                assert net.master.next_seq(node) == rnd
                replies.append(await net.master.atransact(node, b"ping"))
                assert threading.active_count() == threads   # no worker, no helper thread
        return replies

    replies = asyncio.run(main())
    assert replies == [bytes([n, r + 1]) + b"ping" for r in range(3) for n in (1, 2, 3)]
    # on the wire: request and reply with the same node and seq, seq 0, 1, 2
    frames = net.spy_frames()
    assert len(frames) == 18
    for i in range(0, 18, 2):
        assert frames[i].node == frames[i + 1].node
        assert frames[i].seq == frames[i + 1].seq == i // 6
    st = net.master.stats
    assert (st.transactions, st.replies, st.failures, st.retries) == (9, 9, 0, 0)


def test_atransact_retries_a_dropped_reply_applied_once(net: Net) -> None:
    async def main() -> bytes:
        assert await net.master.atransact(2, b"start") == bytes([2, 1]) + b"start"   # seq 0
        net.master.set_timeout(0.05, 5)
        expected = bytes([2, 2]) + b"once"
        net.bus.drop_next(2, len(encode(2, expected, net.master.next_seq(2))))
        return await net.master.atransact(2, b"once")

    assert asyncio.run(main()) == bytes([2, 2]) + b"once"   # the original reply, resent
    assert net.counters[2].applied == 2                        # "once" applied exactly once
    st = net.master.stats
    assert st.retries >= 1 and st.timeouts >= 1 and st.replies == 2
    assert net.slaves[2].stats.resent >= 1 and net.slaves[2].stats.processed == 2
    assert net.master.next_seq(2) == 2


def test_atransact_no_reply_restarts_at_seq_zero(net: Net) -> None:
    async def main() -> None:
        assert await net.master.atransact(3, b"a") == bytes([3, 1]) + b"a"
        assert net.master.next_seq(3) == 1
        net.master.set_timeout(0.01, 2)
        with pytest.raises(NoReplyError):
            await net.master.atransact(77, b"?")   # nobody there
        st = net.master.stats
        assert (st.timeouts, st.retries, st.failures) == (3, 2, 1)
        assert net.master.next_seq(77) == 0
        net.master.set_timeout(0.05, 0)
        net.bus.drop_next(3, len(encode(3, bytes([3, 2]) + b"b", 1)))
        with pytest.raises(NoReplyError):
            await net.master.atransact(3, b"b")    # the reply is lost, no retry left
        assert net.master.next_seq(3) == 0         # the slave may have applied it
        net.master.set_timeout(1.0, 5)
        assert await net.master.atransact(3, b"c") == bytes([3, 3]) + b"c"

    asyncio.run(main())


def test_cancel_leaves_the_master_usable(net: Net) -> None:
    async def main() -> None:
        assert net.master.next_seq(1) == 0
        await net.master.atransact(1, b"x")
        task = asyncio.create_task(net.master.atransact(9, b"absent"))   # 1 s timeout
        await asyncio.sleep(0.02)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert net.master.stats.failures == 1
        assert net.master.next_seq(9) == 0
        assert await net.master.atransact(1, b"y") == bytes([1, 2]) + b"y"
        # and with wait_for, while the slave is being asked
        with pytest.raises(asyncio.TimeoutError):
            await asyncio.wait_for(net.master.atransact(77, b"z"), 0.01)
        assert net.master.transact(1, b"sync") == bytes([1, 3]) + b"sync"

    asyncio.run(main())


def test_abroadcast_reaches_every_slave(net: Net) -> None:
    async def main() -> None:
        await net.master.abroadcast(b"all")
        assert await net.master.atransact(2, b"after") == bytes([2, 1]) + b"after"

    asyncio.run(main())
    for n in (1, 2, 3):
        assert net.counters[n].broadcast_seen.wait(2.0)
        assert net.counters[n].broadcasts == [b"all"]
        assert net.counters[n].applied == (1 if n == 2 else 0)
    assert net.master.stats.broadcasts == 1


def test_concurrent_awaits_on_different_masters() -> None:
    """Three buses, each a master and a slave: gather() interleaves them in
    one loop thread; tasks on one master take turns."""
    buses = [VirtualBus(ports=2) for _ in range(3)]
    counters = [Counter(5) for _ in buses]
    slaves = [Slave(b.paths[1], node=5, handler=c.handler, rs485=LINE).start()
              for b, c in zip(buses, counters)]
    masters = [Master(b.paths[0], timeout=1.0, retries=5, rs485=LINE) for b in buses]
    try:
        async def one(i: int, m: Master) -> List[Tuple[int, bytes]]:
            return [(i, await m.atransact(5, bytes([i, k]))) for k in range(5)]

        async def main() -> List[List[Tuple[int, bytes]]]:
            threads = threading.active_count()
            tasks = [one(i, m) for i, m in enumerate(masters)]
            tasks += [one(10 + i, m) for i, m in enumerate(masters)]   # two tasks per master
            out = await asyncio.gather(*tasks)
            assert threading.active_count() == threads
            return out

        results = asyncio.run(main())
        for lst in results:
            for i, reply in lst:
                assert reply[0] == 5 and reply[2] == i
        for m, c in zip(masters, counters):
            assert c.applied == 10
            assert m.stats.replies == 10 and m.stats.failures == 0
            assert m.next_seq(5) == 10
    finally:
        for m in masters:
            m.close()
        for s in slaves:
            s.close()
            assert s.error is None
        for b in buses:
            b.close()


def test_close_from_another_task_ends_atransact(net: Net) -> None:
    async def main() -> None:
        task = asyncio.create_task(net.master.atransact(9, b"absent"))
        await asyncio.sleep(0.02)
        net.master.close()
        with pytest.raises(ClosedError):
            await asyncio.wait_for(task, 2)
        with pytest.raises(ClosedError):
            await net.master.atransact(1, b"x")

    asyncio.run(main())


@pytest.mark.direct_only("the refusal guards the port's own engine, which the task holds; a "
                         "daemon client's blocking call has a connection of its own and is queued")
def test_blocking_call_inside_atransact_loop_refused(net: Net) -> None:
    async def main() -> None:
        task = asyncio.create_task(net.master.atransact(9, b"absent"))
        await asyncio.sleep(0.02)
        with pytest.raises(ExecAsyncError):
            net.master.transact(1, b"x")       # would wait for the task forever
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert net.master.transact(1, b"x") == bytes([1, 1]) + b"x"

    asyncio.run(main())


def test_atransact_wire_trace_as_transact(caplog: pytest.LogCaptureFixture) -> None:
    """The C trace hook sees the async transaction as the blocking one."""
    caplog.set_level(logging.DEBUG, logger="fap_py.wire")   # before the master installs its hook
    with VirtualBus(ports=2) as bus, \
            Slave(bus.paths[1], node=4, handler=lambda q: q.data, rs485=LINE).start(), \
            Master(bus.paths[0], rs485=LINE, timeout=1.0, retries=0) as m:
        assert asyncio.run(m.atransact(4, b"\x10ab")) == b"\x10ab"
    frame = encode(4, b"\x10ab", 0)   # the echo reply has the same bytes
    recs = [(r.wire_dir, r.wire_bytes, r.wire_status) for r in caplog.records  # type: ignore[attr-defined]
            if r.name == "fap_py.wire.exec"]
    assert sorted(recs) == sorted([("tx", frame, "ok")] * 2 + [("rx", frame, "ok")] * 2), recs
