"""asyncio front end of the G485 master: no worker thread.

The master's transactions are sans-I/O flows (:mod:`fap_py.g485.master`):
each yields the exchanges it needs and is sent the replies back. Here the
event loop drives them: the request is written (one short call into the
port layer), the port's fd is watched with ``loop.add_reader`` for as long
as the front end is open, every chunk read goes to the transaction's
:class:`~fap_py.g485.master.ReplyWaiter`, and a loop timer raises the
timeout. Timeouts, retries, checks, the wake-up preamble and the stale-input
discard are the sync master's own code. A port without a file descriptor (a
pyserial object such as ``loop://``) falls back to one worker thread.

A write into the port layer returns once the bytes are handed to the
driver (``tcdrain``): on a real RS-485 port that is the request's wire time,
during which the loop is busy (a few ms at most at usual baud rates).
"""
from __future__ import annotations

import asyncio
import functools
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, Iterable, List, Optional, Tuple, TypeVar, Union

from ..errors import ClosedError, FapError, PortGoneError
from .codec import SetCommand
from .errors import RETRYABLE_ERRORS, G485Error, G485FrameError, G485ValueError, NoResponseError
from .master import Check, Data, Flow, G485Master, ReplyWaiter
from .transport import PortSpec

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
        self._fd = master.fd
        self._executor: Optional[ThreadPoolExecutor] = None
        if self._fd is None:  # no fd to watch: one worker thread runs the blocking master
            self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="g485-aio")
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._lock: Optional[asyncio.Lock] = None
        self._watching = -1  # the fd add_reader watches (-1: none)
        self._waiter: Optional[ReplyWaiter] = None
        self._future: Optional["asyncio.Future[bytes]"] = None
        self._timeout: Optional[float] = None
        self._deadline = 0.0
        self._timer: Optional[asyncio.TimerHandle] = None
        self._closed = False
        master._close_hooks.append(self._on_master_closed)

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

    # -- the reader: every chunk from the port -----------------------------------

    def _watch(self) -> None:
        fd = self.master.fd
        if fd is None or fd < 0:
            return
        if fd != self._watching:
            self._unwatch()
            self._loop.add_reader(fd, self._on_readable)  # type: ignore[union-attr]
            self._watching = fd

    def _unwatch(self) -> None:
        if self._watching >= 0 and self._loop is not None:
            self._loop.remove_reader(self._watching)
        self._watching = -1

    def _on_readable(self) -> None:
        io = self.master._io
        try:
            chunk = io.read_nowait(4096)  # type: ignore[union-attr]
        except FapError as exc:
            self._unwatch()  # a vanished port stays readable: do not spin on it
            self._finish(exc=exc)
            return
        waiter = self._waiter
        if not chunk or waiter is None:
            return  # nobody waits: stale input, discarded before the next request anyway
        try:
            raw = waiter.feed(chunk)
        except G485Error as exc:
            self._finish(exc=exc)
            return
        if raw is not None:
            self._finish(raw)
        elif waiter.settle:
            deadline = min(self._deadline, self._loop.time() + waiter.settle)  # type: ignore[union-attr]
            if deadline < self._deadline:
                self._arm(deadline)

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
        self._timer = self._loop.call_at(deadline, self._on_timeout)  # type: ignore[union-attr]

    def _on_timeout(self) -> None:
        self._timer = None
        waiter = self._waiter
        if waiter is None:
            return  # armed for an exchange that is over
        if self._loop.time() < self._deadline:  # type: ignore[union-attr]
            self._timer = self._loop.call_at(self._deadline, self._on_timeout)  # type: ignore[union-attr]
            return
        self._finish(exc=waiter.expired(self._timeout))

    def _finish(self, raw: Optional[bytes] = None, exc: Optional[BaseException] = None) -> None:
        fut = self._future
        if fut is None or fut.done():
            return
        self._waiter = None
        if exc is not None:
            fut.set_exception(exc)
        else:
            fut.set_result(raw)  # type: ignore[arg-type]

    # -- driving the flows -----------------------------------------------------------

    async def _exchange(self, frame: bytes, prefix: Optional[bytes], timeout: Optional[float]) -> Optional[bytes]:
        m = self.master
        io = m._io
        if self._watching < 0:  # first exchange, or after the port failed
            self._watch()
        if m._fast_io:  # a late reply to an earlier request is not this one's: discard + write in C
            io.send_fresh(m._wire(frame))  # type: ignore[union-attr]
        else:
            io.flush_input()  # type: ignore[union-attr]
            io.write(m._wire(frame))  # type: ignore[union-attr]
        if prefix is None:
            return None
        loop = self._loop
        self._waiter = ReplyWaiter(m, prefix)
        self._timeout = timeout
        self._future = fut = loop.create_future()  # type: ignore[union-attr]
        self._arm(loop.time() + m._reply_wait(prefix, timeout))  # type: ignore[union-attr]
        try:
            return await fut
        finally:
            self._waiter = None
            self._future = None

    async def _drive(self, flow: Flow) -> Any:
        try:
            step = next(flow)
            while True:
                step = flow.send(await self._exchange(*step))
        except StopIteration as done:
            return done.value

    async def _run_locked(self, make_flow: Callable[..., Flow], retries: Optional[int], *args: Any) -> Any:
        return await self._attempts(self._flow_attempt, retries, make_flow, *args)

    async def _flow_attempt(self, make_flow: Callable[..., Flow], *args: Any) -> Any:
        return await self._drive(make_flow(*args))

    async def _attempts(self, attempt: Callable[..., Any], retries: Optional[int], *args: Any) -> Any:
        """``await attempt(*args)`` until it succeeds or the retries are used up (the lock is held);
        the bookkeeping between attempts is the sync master's."""
        m = self.master
        if m._io is None or m._io.closed or self._closed:
            raise ClosedError(f"{m.name}: master closed")
        if m._gone:
            m._before()  # reopen: the fd may be a new one
            self._unwatch()
        m.stats.transactions += 1
        tries = (m.retries if retries is None else retries) + 1
        n = 0
        while True:
            try:
                return await attempt(*args)
            except RETRYABLE_ERRORS as exc:
                n += 1
                if n >= tries:
                    m._after_failure(exc)
                    raise
                m._recover(exc)
            except PortGoneError:
                m._gone = True
                self._unwatch()
                raise

    def _begin(self) -> asyncio.Lock:
        loop = asyncio.get_running_loop()
        if self._loop is not loop:
            self._unwatch()
            self._timer = None  # belonged to the old loop
            self._loop = loop
            self._lock = asyncio.Lock()
        return self._lock  # type: ignore[return-value]

    async def _run(self, make_flow: Callable[..., Flow], retries: Optional[int], *args: Any) -> Any:
        async with self._begin():
            return await self._run_locked(make_flow, retries, *args)

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
        m = self.master
        if check is None and timeout is None and retries is None and m.check is Check.NONE:
            plan = m._read_plans.get((address, register, count)) if type(address) is int else None
            if plan is not None and plan[3] is register and plan[4] is count:
                return await self._read_none(plan, address)  # the hot path: one exchange, no flow
        make, r, *args = m._plan_read(address, register, count, check, timeout, retries)
        return await self._run(make, r, *args)

    async def _read_none(self, plan: Any, address: int) -> bytes:
        """:meth:`G485Master._read_none` on the loop: no flow object."""
        async with self._begin():
            return await self._attempts(self._read_none_attempt, None, plan, address)

    async def _read_none_attempt(self, plan: Any, address: int) -> bytes:
        reply = await self._exchange(plan[0], plan[1], None)
        self.master._device_check[address] = reply[-1]  # type: ignore[index]
        return reply[5:-1]  # type: ignore[index]

    async def write(self, address: int, register: int, data: Data, *,
                    check: Union[Check, str, None] = None, timeout: Optional[float] = None,
                    retries: Optional[int] = None) -> None:
        """See :meth:`G485Master.write`."""
        if self._executor is not None:
            return await self._call(self.master.write, address, register, data, check=check,
                                    timeout=timeout, retries=retries)
        (make, r, *args), after = self.master._plan_write(address, register, data, check, timeout, retries)
        await self._run(make, r, *args)
        after()

    async def error_word(self, address: int, *, check: Union[Check, str, None] = None,
                         timeout: Optional[float] = None, retries: Optional[int] = None) -> int:
        """See :meth:`G485Master.error_word`."""
        if self._executor is not None:
            return await self._call(self.master.error_word, address, check=check, timeout=timeout,
                                    retries=retries)
        make, r, *args = self.master._plan_error_word(address, check, timeout, retries)
        return await self._run(make, r, *args)

    async def set(self, address: int, command: Union[SetCommand, int, str], *,
                  check: Union[Check, str, None] = None, guard: Optional[bool] = None,
                  timeout: Optional[float] = None, retries: Optional[int] = None,
                  factory_address: Optional[int] = None) -> None:
        """See :meth:`G485Master.set`."""
        if self._executor is not None:
            return await self._call(self.master.set, address, command, check=check, guard=guard,
                                    timeout=timeout, retries=retries, factory_address=factory_address)
        (make, r, *args), after = self.master._plan_set(address, command, check, guard, timeout, retries,
                                                        factory_address)
        await self._run(make, r, *args)
        after()

    async def handshake(self, address: int, *, timeout: Optional[float] = None,
                        retries: Optional[int] = None) -> int:
        """See :meth:`G485Master.handshake`."""
        if self._executor is not None:
            return await self._call(self.master.handshake, address, timeout=timeout, retries=retries)
        make, r, *args = self.master._plan_handshake(address, timeout, retries)
        return await self._run(make, r, *args)

    async def scan(self, addresses: Iterable[int] = range(1, 127), *, timeout: Optional[float] = None,
                   retries: Optional[int] = 0) -> List[int]:
        """See :meth:`G485Master.scan`."""
        m = self.master
        if self._executor is not None:
            return await self._call(m.scan, addresses, timeout=timeout, retries=retries)
        from .master import _retries_arg, _timeout_arg

        items = m._scan_addresses(addresses)
        timeout, retries = _timeout_arg(timeout), _retries_arg(retries)
        found = []
        for address in items:
            try:
                found.append(await self._run(m._scan_flow, retries, address, timeout))
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
        items = m._sync_items(writes)
        async with self._begin():
            done: List[int] = []

            async def do_set(address: int, cmd: SetCommand) -> None:
                (make, r, *args), after = m._plan_set(address, cmd, check, None, None, None, None)
                await self._run_locked(make, r, *args)
                after()

            for address, register, data in items:
                if address not in done:
                    await do_set(address, SetCommand.NON_REAL_TIME_WRITE)
                    done.append(address)
                (make, r, *args), after = m._plan_write(address, register, data, check, None, None)
                await self._run_locked(make, r, *args)
                after()
            for _ in range(apply_repeats):
                await do_set(0, SetCommand.APPLY_WRITES)
            if back_to_real_time:
                for address in done:
                    await do_set(address, SetCommand.REAL_TIME_WRITE)

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
