"""asyncio front end of the G485 master.

A G485 bus is strictly one transaction at a time, so the asyncio variant
runs the blocking :class:`~fap_py.g485.master.G485Master` in one dedicated
worker thread: coroutines queue their transactions there in order, the event
loop never blocks, and the master's own timeouts, retries and checks apply
unchanged. (Per transaction this costs a thread hand-off, a few tens of µs.)
"""
from __future__ import annotations

import asyncio
import functools
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Iterable, Optional, Tuple, TypeVar, Union

from .codec import SetCommand
from .master import Check, Data, G485Master
from .transport import PortSpec

T = TypeVar("T")


class AsyncG485Master:
    """``async with AsyncG485Master(port, baudrate, **options) as bus: await bus.read(1, 1, 7)``.

    Takes the same arguments as :class:`G485Master` (or ``master=`` an existing one).
    """

    def __init__(self, port: Optional[PortSpec] = None, baudrate: int = 115200, *,
                 master: Optional[G485Master] = None, **options: Any) -> None:
        if master is None:
            if port is None:
                raise TypeError("give a port or an existing master")
            master = G485Master(port, baudrate, **options)
        self.master = master
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="g485-aio")

    async def _call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._executor, functools.partial(fn, *args, **kwargs))

    async def read(self, address: int, register: int, count: int = 1, **kwargs: Any) -> bytes:
        """See :meth:`G485Master.read`."""
        return await self._call(self.master.read, address, register, count, **kwargs)

    async def write(self, address: int, register: int, data: Data, **kwargs: Any) -> None:
        """See :meth:`G485Master.write`."""
        await self._call(self.master.write, address, register, data, **kwargs)

    async def error_word(self, address: int, **kwargs: Any) -> int:
        """See :meth:`G485Master.error_word`."""
        return await self._call(self.master.error_word, address, **kwargs)

    async def set(self, address: int, command: Union[SetCommand, int, str], **kwargs: Any) -> None:
        """See :meth:`G485Master.set`."""
        await self._call(self.master.set, address, command, **kwargs)

    async def handshake(self, address: int, **kwargs: Any) -> int:
        """See :meth:`G485Master.handshake`."""
        return await self._call(self.master.handshake, address, **kwargs)

    async def sync_write(self, writes: Iterable[Tuple[int, int, Data]], *,
                         check: Union[Check, str, None] = None, **kwargs: Any) -> None:
        """See :meth:`G485Master.sync_write`."""
        await self._call(self.master.sync_write, list(writes), check=check, **kwargs)

    async def aclose(self) -> None:
        """Close the port and stop the worker thread."""
        await self._call(self.master.close)
        self._executor.shutdown(wait=True)

    async def __aenter__(self) -> "AsyncG485Master":
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()
