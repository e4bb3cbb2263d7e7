"""asyncio driver of the G485 master: no worker thread.

The transactions are sans-I/O (:mod:`fap_py.g485.transaction`): a
:class:`~fap_py.g485.transaction.Transaction` says what to send and until
when to wait, and is handed what arrives. Here the event loop performs
that: the request is written (one short call into the port layer), the
port's fd is watched with ``loop.add_reader`` for as long as the front end
is open, every chunk read goes to the transaction, and a loop timer tells it
when its deadline passed. Timeouts, retries, checks, the wake-up preamble
and the reply matching are the transaction's, shared with the blocking
:class:`~fap_py.g485.master.G485Master`. A port without a file descriptor (a
pyserial object such as ``loop://``) falls back to one worker thread.

A write into the port layer returns once the bytes are handed to the
driver (``tcdrain``): on a real RS-485 port that is the request's wire time,
during which the loop is busy (a few ms at most at usual baud rates).
"""
from __future__ import annotations

import asyncio
import functools
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Iterable, Iterator, List, Optional, Tuple, TypeVar, Union

from ..errors import ClosedError, FapError, PortGoneError
from .codec import Data, SetCommand
from .errors import G485FrameError, G485ValueError, NoResponseError
from .master import G485Master
from .transaction import Action, Check, Done, Send, Transaction, Wait
from .transport import IO, PortIO, PortSpec

T = TypeVar("T")


class AsyncG485Master:
    """``async with AsyncG485Master(port, baudrate, **options) as bus: await bus.read(1, 1, 7)``.

    Takes the same arguments as :class:`G485Master` (or ``master=`` an existing
    one, which this front end then drives; do not use it from other threads
    at the same time).
    """

    def __init__(self, port: Optional[PortSpec] = None, baudrate: int = 115200, *,
                 master: Optional[G485Master] = None, **options: Any) -> None:
        if master is None:
            if port is None:
                raise G485ValueError("give a port or an existing master")
            master = G485Master(port, baudrate, **options)
        elif not isinstance(master, G485Master):
            raise G485ValueError(f"master must be a G485Master, not {type(master).__name__}")
        self.master = master
        self._executor: Optional[ThreadPoolExecutor] = None
        if master.fd is None:  # no fd to watch: one worker thread runs the blocking master
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="g485-aio")
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._lock: Optional[asyncio.Lock] = None
        self._watching = -1  # the fd add_reader watches (-1: none)
        self._tx: Optional[Transaction] = None  # the transaction awaiting bytes
        self._future: Optional["asyncio.Future[Action]"] = None
        self._deadline = 0.0
        self._timer: Optional[asyncio.TimerHandle] = None
        self._closed = False
        master.on_close(self._on_master_closed)

    def _on_master_closed(self) -> None:
        """The master was closed (here or from another thread): the exchange in
        flight ends with ClosedError now, not at its timeout."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        exc = ClosedError(f"{self.master.name}: master closed")
        try:
            running: Optional[asyncio.AbstractEventLoop] = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            self._fail_closed(exc)
        else:
            try:
                loop.call_soon_threadsafe(self._fail_closed, exc)
            except RuntimeError:  # its loop closed meanwhile
                pass

    def _fail_closed(self, exc: ClosedError) -> None:
        self._unwatch()
        self._finish(exc=exc)

    def _running_loop(self) -> asyncio.AbstractEventLoop:
        loop = self._loop
        assert loop is not None, "used outside a transaction"
        return loop

    # -- the reader: every chunk from the port -----------------------------------

    def _watch(self) -> None:
        fd = self.master.fd
        if fd is None or fd < 0:
            return
        if fd != self._watching:
            self._unwatch()
            self._running_loop().add_reader(fd, self._on_readable)
            self._watching = fd

    def _unwatch(self) -> None:
        if self._watching >= 0 and self._loop is not None:
            self._loop.remove_reader(self._watching)
        self._watching = -1

    def _on_readable(self) -> None:
        try:
            chunk = self.master.io.read_nowait(4096)
        except FapError as exc:
            self._unwatch()  # a vanished port stays readable: do not spin on it
            self._finish(exc=exc)
            return
        tx = self._tx
        if not chunk or tx is None:
            return  # nobody waits: stale input, discarded before the next request anyway
        try:
            action = tx.receive(chunk, self._running_loop().time())
        except FapError as exc:
            self._finish(exc=exc)
            return
        self._step(action)

    def _on_timeout(self) -> None:
        self._timer = None
        tx = self._tx
        if tx is None:
            return  # armed for an exchange that is over
        loop = self._running_loop()
        if loop.time() < self._deadline:  # an early timer: wait on
            self._timer = loop.call_at(self._deadline, self._on_timeout)
            return
        try:
            action = tx.expire(loop.time())
        except FapError as exc:
            self._finish(exc=exc)
            return
        self._step(action)

    def _step(self, action: Action) -> None:
        """More bytes wanted: keep waiting (maybe less long); anything else ends the wait."""
        if type(action) is Wait:
            self._arm(action.deadline)
        else:
            self._finish(action)

    def _arm(self, deadline: float) -> None:
        """Wake up at ``deadline`` at the latest. One timer serves many exchanges: it is
        re-armed only when it would fire too late, and a timer that fires early (the
        exchange it was set for is over) re-arms itself for the current deadline."""
        self._deadline = deadline
        timer = self._timer
        if timer is not None:
            if timer.when() <= deadline:
                return
            timer.cancel()
        self._timer = self._running_loop().call_at(deadline, self._on_timeout)

    def _finish(self, action: Optional[Action] = None, exc: Optional[BaseException] = None) -> None:
        fut = self._future
        if fut is None or fut.done():
            return
        self._tx = None
        if action is not None:
            fut.set_result(action)
        else:
            fut.set_exception(exc or ClosedError(f"{self.master.name}: exchange abandoned"))

    # -- the driver ------------------------------------------------------------------

    def _ready(self) -> IO:
        if self._closed:
            raise ClosedError(f"{self.master.name}: master closed")
        gone = self.master.session.gone
        io = self.master.ready_io()  # reopens a vanished port: the fd may be a new one
        if gone:
            self._unwatch()
        if self._watching < 0:  # first exchange, or after the port failed
            self._watch()
        return io

    async def _drive(self, tx: Transaction) -> Any:
        """Do what ``tx`` asks until it is done (the caller holds the lock)."""
        loop = self._running_loop()
        io = self._ready()
        action: Action = tx.start(loop.time())
        try:
            while True:
                if isinstance(action, Send):
                    if isinstance(io, PortIO):  # discard stale input and write: one call into C
                        io.send_fresh(action.wire)
                    else:
                        io.flush_input()
                        io.write(action.wire)
                    if not action.size:
                        action = tx.written(loop.time())
                        continue
                    action = await self._reply(tx, action.deadline)
                elif isinstance(action, Wait):
                    action = await self._reply(tx, action.deadline)
                elif isinstance(action, Done):
                    return action.value
                else:
                    io.flush_input()
                    raise action.error
        except PortGoneError:
            self.master.session.port_gone()
            self._unwatch()
            raise

    async def _reply(self, tx: Transaction, deadline: float) -> Action:
        """Wait for the reader or the timer to move ``tx`` on."""
        self._tx = tx
        self._future = fut = self._running_loop().create_future()
        self._arm(deadline)
        try:
            return await fut
        finally:
            self._tx = None
            self._future = None

    def _begin(self) -> asyncio.Lock:
        loop = asyncio.get_running_loop()
        if self._loop is not loop or self._lock is None:
            self._unwatch()
            self._timer = None  # belonged to the old loop
            self._loop = loop
            self._lock = asyncio.Lock()
        return self._lock

    async def _run(self, tx: Transaction) -> Any:
        async with self._begin():
            return await self._drive(tx)

    async def _run_all(self, txs: Iterator[Transaction]) -> None:
        async with self._begin():
            for tx in txs:
                await self._drive(tx)

    async def _call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """The fallback without an fd: the blocking master in the worker thread."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._executor, functools.partial(fn, *args, **kwargs))

    # -- transactions -----------------------------------------------------------------

    async def read(self, address: int, register: int, count: int = 1, *,
                   check: Union[Check, str, None] = None, timeout: Optional[float] = None,
                   retries: Optional[int] = None) -> bytes:
        """See :meth:`G485Master.read`."""
        if self._executor is not None:
            return await self._call(self.master.read, address, register, count, check=check, timeout=timeout,
                                    retries=retries)
        return await self._run(self.master.session.read(address, register, count, check, timeout, retries))

    async def write(self, address: int, register: int, data: Data, *,
                    check: Union[Check, str, None] = None, timeout: Optional[float] = None,
                    retries: Optional[int] = None) -> None:
        """See :meth:`G485Master.write`."""
        if self._executor is not None:
            return await self._call(self.master.write, address, register, data, check=check,
                                    timeout=timeout, retries=retries)
        await self._run(self.master.session.write(address, register, data, check, timeout, retries))

    async def error_word(self, address: int, *, check: Union[Check, str, None] = None,
                         timeout: Optional[float] = None, retries: Optional[int] = None) -> int:
        """See :meth:`G485Master.error_word`."""
        if self._executor is not None:
            return await self._call(self.master.error_word, address, check=check, timeout=timeout,
                                    retries=retries)
        return await self._run(self.master.session.error_word(address, check, timeout, retries))

    async def set(self, address: int, command: Union[SetCommand, int, str], *,
                  check: Union[Check, str, None] = None, guard: Optional[bool] = None,
                  timeout: Optional[float] = None, retries: Optional[int] = None,
                  factory_address: Optional[int] = None) -> None:
        """See :meth:`G485Master.set`."""
        if self._executor is not None:
            return await self._call(self.master.set, address, command, check=check, guard=guard,
                                    timeout=timeout, retries=retries, factory_address=factory_address)
        await self._run(self.master.session.set(address, command, check, guard, timeout, retries,
                                                factory_address))

    async def handshake(self, address: int, *, timeout: Optional[float] = None,
                        retries: Optional[int] = None) -> int:
        """See :meth:`G485Master.handshake`."""
        if self._executor is not None:
            return await self._call(self.master.handshake, address, timeout=timeout, retries=retries)
        return await self._run(self.master.session.handshake(address, timeout, retries))

    async def scan(self, addresses: Iterable[int] = range(1, 127), *, timeout: Optional[float] = None,
                   retries: Optional[int] = 0) -> List[int]:
        """See :meth:`G485Master.scan`."""
        m = self.master
        if self._executor is not None:
            return await self._call(m.scan, addresses, timeout=timeout, retries=retries)
        s = m.session
        found = []
        for tx in [s.probe(a, timeout, retries) for a in s.scan_addresses(addresses)]:
            try:
                found.append(await self._run(tx))
            except (NoResponseError, G485FrameError):
                pass
        return found

    async def sync_write(self, writes: Iterable[Tuple[int, int, Data]], *,
                         check: Union[Check, str, None] = None, apply_repeats: int = 1,
                         back_to_real_time: bool = False) -> None:
        """See :meth:`G485Master.sync_write` (the whole sequence holds the front end's lock)."""
        m = self.master
        if self._executor is not None:
            return await self._call(m.sync_write, list(writes), check=check, apply_repeats=apply_repeats,
                                    back_to_real_time=back_to_real_time)
        await self._run_all(m.session.sync_write(writes, check, apply_repeats, back_to_real_time))

    # -- lifetime ---------------------------------------------------------------------

    async def aclose(self) -> None:
        """Stop watching the port and close it."""
        if self._closed:
            return
        self._closed = True
        if self._executor is not None:
            await self._call(self.master.close)
            self._executor.shutdown(wait=True)
            return
        self._unwatch()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.master.close()

    async def __aenter__(self) -> "AsyncG485Master":
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()
