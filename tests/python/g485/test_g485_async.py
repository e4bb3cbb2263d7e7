"""The asyncio G485 master: flows driven by the event loop, no worker thread."""
from __future__ import annotations

import asyncio
import threading

import pytest

from fap_py.g485 import G485Master, NoResponseError, SetCommand, SimDevice, Simulator, WriteRefusedError
from fap_py.g485.aio import AsyncG485Master

FAST = 0.5


def _threads() -> set:
    return {t.name for t in threading.enumerate()}


def test_no_worker_thread_and_every_transaction(vbus) -> None:
    devs = [SimDevice(2), SimDevice(9)]

    async def main() -> None:
        before = _threads()
        async with AsyncG485Master(vbus.paths[0], 115200, timeout=FAST) as bus:
            assert bus._executor is None
            await bus.write(2, 8, [4, 5])
            assert await bus.read(2, 8, 2) == b"\x04\x05"
            results = await asyncio.gather(*(bus.read(9, 7, check=c) for c in ("none", "handshake", "reread") * 4))
            assert results == [b"\x09"] * 12
            assert await bus.error_word(2) == 0
            await bus.set(2, SetCommand.SAVE_EEPROM)
            assert await bus.handshake(2) == devs[0].check_byte
            await bus.sync_write([(2, 9, 1), (9, 9, 2)])
            assert await bus.scan(range(1, 12), timeout=0.02, retries=2) == [2, 9]
            with pytest.raises(NoResponseError):
                await bus.read(7, 1, timeout=0.02, retries=0)
            with pytest.raises(WriteRefusedError):
                await bus.write(2, 3, [1], retries=0)  # read-only register
            assert _threads() == before  # nothing started a thread
            assert bus.master.stats.transactions > 20

    with Simulator(vbus.paths[1], devs) as sim:
        asyncio.run(main())
        assert sim.error is None
    assert devs[0].applied[9] == 1 and devs[1].applied[9] == 2


def test_timeout_does_not_block_the_loop(vbus) -> None:
    """While a read waits for an absent device, other coroutines run."""

    async def main() -> int:
        ticks = 0

        async def ticker() -> None:
            nonlocal ticks
            while True:
                ticks += 1
                await asyncio.sleep(0.005)

        async with AsyncG485Master(vbus.paths[0], 115200, timeout=0.2, retries=0) as bus:
            task = asyncio.ensure_future(ticker())
            with pytest.raises(NoResponseError):
                await bus.read(5, 7)
            task.cancel()
        return ticks

    assert asyncio.run(main()) >= 10


def test_drives_an_existing_master_and_pyserial_fallback(vbus) -> None:
    async def main() -> None:
        master = G485Master(vbus.paths[0], timeout=FAST)
        async with AsyncG485Master(master=master) as bus:
            assert await bus.read(3, 7) == b"\x03"
        assert master._io.closed

    with Simulator(vbus.paths[1], [SimDevice(3)]):
        asyncio.run(main())


def test_loop_url_without_fd_uses_one_worker_thread() -> None:
    import serial

    async def main() -> None:
        async with AsyncG485Master(master=G485Master(serial.serial_for_url("loop://", timeout=0.01),
                                                     timeout=0.02, retries=0)) as bus:
            assert bus._executor is not None
            with pytest.raises(NoResponseError):
                await bus.read(3, 8)

    asyncio.run(main())
