"""Exec async slave in an asyncio loop: the port fd drives it, no thread."""
from __future__ import annotations

import asyncio
import threading
from concurrent.futures import ThreadPoolExecutor

from fap_py.errors import ClosedError
from fap_py.execasync import Master, Request, ServeResult, Slave
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)


def test_aserve_answers_without_a_thread() -> None:
    seen = []

    def handler(req: Request) -> bytes:
        seen.append(threading.current_thread())
        return req.data[::-1]

    async def main(bus: VirtualBus) -> None:
        threads = threading.active_count()
        async with Slave(bus.paths[1], node=3, handler=handler, rs485=LINE) as slave:
            server = asyncio.create_task(slave.aserve_forever())
            loop = asyncio.get_running_loop()
            with Master(bus.paths[0], timeout=0.5, rs485=LINE) as master, \
                    ThreadPoolExecutor(max_workers=1) as pool:
                for i in range(5):
                    data = bytes([i, 1, 2])
                    # the blocking master runs in one worker; the slave stays in the loop
                    reply = await loop.run_in_executor(pool, master.transact, 3, data)
                    assert reply == data[::-1]
                    assert threading.active_count() <= threads + 1   # + that worker only
            assert slave.stats.processed == 5
            await slave.aclose()
            await asyncio.wait_for(server, 2)     # aserve_forever ends on close

    with VirtualBus(ports=2) as bus:
        asyncio.run(main(bus))
    assert seen and all(t is threading.main_thread() for t in seen)


def test_aserve_times_out_and_after_close_raises() -> None:
    async def main(bus: VirtualBus) -> None:
        slave = Slave(bus.paths[1], node=3, handler=lambda r: b"", rs485=LINE)
        assert await slave.aserve(0.02) is ServeResult.TIMEOUT
        waiter = asyncio.create_task(slave.aserve(None))
        await asyncio.sleep(0)
        slave.close()                           # from the loop's thread, while a waiter waits
        try:
            await asyncio.wait_for(waiter, 2)
        except ClosedError:
            pass
        else:
            raise AssertionError("aserve returned after close")

    with VirtualBus(ports=2) as bus:
        asyncio.run(main(bus))
