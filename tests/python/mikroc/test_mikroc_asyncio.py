"""mikroC nodes in an asyncio loop: areceive waits on the port fd (add_reader), no thread."""
from __future__ import annotations

import asyncio
import threading

import pytest

from fap_py.errors import ClosedError, FapTimeoutError
from fap_py.mikroc import Master, Slave
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)


def test_request_and_reply_in_one_loop() -> None:
    async def slave_loop(s: Slave, n: int) -> None:
        for _ in range(n):
            msg = await s.areceive(timeout=2)
            s.send(bytes([msg.data[0] + 1]))

    async def main(bus: VirtualBus) -> None:
        threads = threading.active_count()
        with Master(bus.paths[0], rs485=LINE) as m, Slave(bus.paths[1], address=0x12, rs485=LINE) as s:
            task = asyncio.create_task(slave_loop(s, 4))
            for i in range(4):
                reply = await m.arequest(0x12, bytes([i]), timeout=2)
                assert reply.address == 0x12 and reply.data == bytes([i + 1])
            await task
            assert threading.active_count() == threads      # no worker thread
            with pytest.raises(FapTimeoutError):
                await m.areceive(timeout=0.02)

    with VirtualBus(ports=2) as bus:
        asyncio.run(main(bus))


def test_areceive_ends_with_closed_when_closed() -> None:
    async def main(bus: VirtualBus) -> None:
        s = Slave(bus.paths[1], address=5, rs485=LINE)
        waiter = asyncio.create_task(s.areceive(timeout=None))
        await asyncio.sleep(0.01)
        s.close()
        with pytest.raises(ClosedError):
            await asyncio.wait_for(waiter, 2)

    with VirtualBus(ports=2) as bus:
        asyncio.run(main(bus))
