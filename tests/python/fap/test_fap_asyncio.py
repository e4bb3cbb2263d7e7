"""The asyncio path: arecv / async for / await_event / aevents, driven by the notify fd."""
from __future__ import annotations

import asyncio
import threading
import time
from typing import List, Tuple

import pytest
from conftest import FAST, SLAVE_IDS, WAIT

from fap_py import ClosedError, EventKind, FapTimeoutError, Master, Message, Slave
from fap_py.vbus import VirtualBus

Net = Tuple[Master, List[Slave]]


def run(coro) -> object:
    return asyncio.run(asyncio.wait_for(coro, WAIT * 2))


def test_arecv_both_directions(net: Net) -> None:
    master, slaves = net

    async def main() -> None:
        for s in slaves:
            master.send(bytes([s.id]) * 1024, to=s.id)
        got = await asyncio.gather(*(s.arecv(timeout=WAIT) for s in slaves))
        assert got == [Message(0, bytes([s.id]) * 1024) for s in slaves]
        for s in slaves:
            s.send(b"up from %d" % s.id)
        back = [await master.arecv(timeout=WAIT) for _ in slaves]
        assert sorted(m.source for m in back) == sorted(SLAVE_IDS)

    run(main())


@pytest.mark.direct_only("a daemon client's arecv waits in the loop's executor, not on a notification fd (docs/daemon.md)")
def test_arecv_waits_for_the_fd_without_busy_looping(net: Net) -> None:
    master, (a, _, _) = net

    async def main() -> None:
        loop = asyncio.get_running_loop()
        threads = threading.active_count()
        cpu0 = time.thread_time()
        t0 = time.monotonic()
        with pytest.raises(FapTimeoutError):
            await master.arecv(timeout=0.5)
        waited, cpu = time.monotonic() - t0, time.thread_time() - cpu0
        assert waited >= 0.45
        # the loop thread slept in epoll for the whole wait: a busy or polling
        # loop would burn a large share of the 0.5 s
        assert cpu < 0.1, f"loop thread used {cpu:.3f} s CPU while waiting"
        # the message arrives through the reader callback on the notify fd
        fd = master.fileno()
        assert fd in loop._selector.get_map()  # type: ignore[attr-defined]
        assert threading.active_count() == threads      # no helper thread was started
        waiter = asyncio.ensure_future(master.arecv(timeout=WAIT))
        await asyncio.sleep(0)        # let it block (scheduling, not synchronisation)
        a.send(b"wake")
        assert await waiter == Message(a.id, b"wake")

    run(main())


def test_async_for_and_close_ends_iteration(bus: VirtualBus) -> None:
    async def main() -> None:
        async with Master(bus.paths[0], slaves=[2], **FAST) as master, \
                Slave(bus.paths[1], id=2) as s:
            for i in range(5):
                s.send(bytes([i]))
            seen = []
            async for msg in master:
                seen.append(msg.data[0])
                if len(seen) == 5:
                    break
            assert seen == [0, 1, 2, 3, 4]

            got: List[Message] = []
            first = asyncio.Event()

            async def consume() -> None:
                async for m in s:          # ends when s is closed
                    got.append(m)
                    first.set()

            task = asyncio.ensure_future(consume())
            master.send(b"last", to=2)
            await first.wait()
            await s.aclose()
            await task
            assert got == [Message(0, b"last")] and s.closed

    run(main())


def test_async_events_slave_leaves_and_returns(bus: VirtualBus) -> None:
    async def main() -> None:
        async with Master(bus.paths[0], slaves=SLAVE_IDS, **FAST) as master:
            slaves = [Slave(p, id=i) for p, i in zip(bus.paths[1:], SLAVE_IDS)]
            try:
                joined = set()
                async for ev in master.aevents(timeout=WAIT):
                    if ev.kind is EventKind.SLAVE_ACTIVE:
                        joined.add(ev.id)
                    if joined == set(SLAVE_IDS):
                        break
                assert master.active_slaves == sorted(SLAVE_IDS)
                slaves[0].close()
                ev = await master.await_event(timeout=WAIT)
                while not (ev.kind is EventKind.SLAVE_INACTIVE and ev.id == SLAVE_IDS[0]):
                    ev = await master.await_event(timeout=WAIT)
                slaves[0] = Slave(bus.paths[1], id=SLAVE_IDS[0])
                while not (ev.kind is EventKind.SLAVE_ACTIVE and ev.id == SLAVE_IDS[0]):
                    ev = await master.await_event(timeout=WAIT)
                slaves[0].send(b"back")
                assert await master.arecv(timeout=WAIT) == Message(SLAVE_IDS[0], b"back")
            finally:
                for s in slaves:
                    s.close()

    run(main())


def test_cancelled_arecv_loses_nothing(net: Net) -> None:
    master, (a, _, _) = net

    async def main() -> None:
        waiter = asyncio.ensure_future(master.arecv())
        await asyncio.sleep(0)
        waiter.cancel()
        with pytest.raises(asyncio.CancelledError):
            await waiter
        a.send(b"kept")
        assert await master.arecv(timeout=WAIT) == Message(a.id, b"kept")
        # a timeout is a FapTimeoutError (a TimeoutError)
        with pytest.raises(TimeoutError):
            await master.arecv(timeout=0.05)

    run(main())


def test_close_from_another_thread_fails_async_waiters(bus: VirtualBus) -> None:
    s = Slave(bus.paths[1], id=1)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        fd = s.fileno()
        waiter = asyncio.ensure_future(s.arecv())
        ev_waiter = asyncio.ensure_future(s.await_event())
        await asyncio.sleep(0)
        assert fd in loop._selector.get_map()  # type: ignore[attr-defined]
        await loop.run_in_executor(None, s.close)     # close() runs in a worker thread
        with pytest.raises(ClosedError):
            await waiter
        with pytest.raises(ClosedError):             # no master: no event ever came
            await ev_waiter
        assert s.closed
        assert fd not in loop._selector.get_map()  # type: ignore[attr-defined]
        with pytest.raises(ClosedError):
            await s.arecv()

    run(main())


def test_small_queue_backpressure_keeps_order(bus: VirtualBus) -> None:
    """A full Python deque pauses the reader; frames then wait in C, none is lost."""
    async def until(cond, what: str) -> None:
        deadline = time.monotonic() + WAIT
        while not cond():
            assert time.monotonic() < deadline, what
            await asyncio.sleep(0.001)     # let the loop run the reader

    async def main() -> None:
        loop = asyncio.get_running_loop()
        async with Master(bus.paths[0], slaves=[6], rx_queue=4, **FAST) as master, \
                Slave(bus.paths[1], id=6, tx_queue=16) as s:
            await master.await_event(timeout=WAIT)       # attaches the pump
            pump = master._pump
            assert pump is not None
            for i in range(4):
                s.send(bytes([i]))
            await loop.run_in_executor(None, s.flush, WAIT)
            await until(lambda: pump.paused, "reader never paused")
            assert pump.rx_queued() == 4 and not pump.reading
            for i in range(4, 8):                        # these wait in the C queue
                s.send(bytes([i]))
            await loop.run_in_executor(None, s.flush, WAIT)
            await until(lambda: master.rx_pending == 8, "frames missing")
            got = [(await master.arecv(timeout=WAIT)).data[0] for _ in range(8)]
            assert got == list(range(8))
            assert master.stats.rx_dropped == 0 and pump.reading and not pump.paused
            # 12 frames > 4 (Python) + 4 (C): the rest overflow in C, reported as events
            for i in range(12):
                s.send(bytes([i]))
            await loop.run_in_executor(None, s.flush, WAIT)
            overflows = 0
            while overflows < 4:                   # one event per dropped frame
                ev = await master.await_event(timeout=WAIT)
                if ev.kind is EventKind.RX_OVERFLOW:
                    assert ev.id == 6
                    overflows += 1
            assert master.stats.rx_dropped >= 4

    run(main())
