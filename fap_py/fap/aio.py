"""asyncio support of :mod:`fap_py.fap`: the C engine's notification fd drives the loop.

One :class:`AsyncPump` per node and event loop. It registers the handle's
notification fd (``fapx_notify_fd``, level-triggered: readable while a
received frame or an event is queued in C) with ``loop.add_reader``. When
it turns readable, the loop thread moves the queued frames and events into
Python deques with the non-blocking ``fapx_rx`` / ``fapx_event_get`` and
wakes the coroutines awaiting them. No thread, no timer, no polling.

Back-pressure: the message deque holds at most the node's ``rx_queue``
depth. When it is full the pump stops reading the fd (frames then wait in,
and eventually overflow, the C queue exactly as for a C program that does
not call ``fapx_rx``) and resumes as soon as a message is taken. While it
is paused, events are still collected every :data:`fap_py._handle.WAIT_SLICE`
seconds. Events beyond ``event_queue`` drop the oldest (counted in
:attr:`AsyncPump.events_dropped`).

Nothing here is called from the C engine thread: Python only ever runs in
the event loop's thread (or the caller's), never in a C callback.
"""
from __future__ import annotations

import asyncio
import logging
import threading
from collections import deque
from typing import TYPE_CHECKING, Any, AsyncIterator, Callable, Deque, Optional, Protocol

from .._handle import WAIT_SLICE
from .._validate import check_timeout
from ..errors import ClosedError, FapError, FapTimeoutError, InvalidTypeError
from .types import Message, SlaveEvent


class PumpedNode(Protocol):
    """What the pump needs of a node (fap.Node): no import of fap.py, no cycle."""

    _rx_depth: int
    _ev_depth: int

    def fileno(self) -> int: ...
    def _label(self) -> str: ...
    def _closed_error(self) -> ClosedError: ...
    def _rx_c(self, wait_ms: Optional[int]) -> Optional[Message]: ...
    def _ev_c(self, wait_ms: Optional[int]) -> Optional[SlaveEvent]: ...

log = logging.getLogger(__name__)

__all__ = ["AsyncPump"]


class AsyncPump:
    """Moves one node's C queues into an asyncio event loop (see the module doc)."""

    def __init__(self, node: "PumpedNode", loop: asyncio.AbstractEventLoop) -> None:
        if not isinstance(loop, asyncio.AbstractEventLoop):
            raise InvalidTypeError(f"loop must be an asyncio event loop, not {type(loop).__name__}")
        if not all(callable(getattr(node, m, None)) for m in ("fileno", "_rx_c", "_ev_c")):
            raise InvalidTypeError(f"node must be a fap_py.fap node, not {type(node).__name__}")
        self.node = node
        self.loop = loop
        self.thread_id = threading.get_ident()    # the loop's thread
        self.fd = node.fileno()
        self.rx_cap = int(node._rx_depth)
        self.rx: Deque["Message"] = deque()
        self.ev: Deque["SlaveEvent"] = deque()
        self.ev_cap = int(node._ev_depth)
        self.rx_waiters: Deque["asyncio.Future[Any]"] = deque()
        self.ev_waiters: Deque["asyncio.Future[Any]"] = deque()
        self.events_dropped = 0     #: events discarded because nobody read them
        self.reading = False
        self.paused = False
        self.stopped = False
        self._poll: Optional[asyncio.TimerHandle] = None

    @classmethod
    def for_running_loop(cls, node: "PumpedNode", current: Optional["AsyncPump"]) -> "AsyncPump":
        """The node's pump for the running loop: ``current`` or a new one."""
        loop = asyncio.get_running_loop()
        if current is not None and not current.stopped:
            if current.loop is loop:
                return current
            if current.loop.is_running():
                raise FapError("this node is attached to another running event loop")
            current.stop()           # its loop is finished: move to this one
        pump = cls(node, loop)
        if current is not None:      # keep what the old loop had collected
            pump.rx.extend(current.rx)
            pump.ev.extend(current.ev)
        pump._start_reading()
        return pump

    # -- fd reader (loop thread) ----------------------------------------------
    def _start_reading(self) -> None:
        if not self.reading and not self.stopped:
            self.loop.add_reader(self.fd, self._on_readable)
            self.reading = True
            self.paused = False

    def _pause(self) -> None:
        if self.reading:
            self.loop.remove_reader(self.fd)
            self.reading = False
        self.paused = True
        if self._poll is None:
            self._poll = self.loop.call_later(WAIT_SLICE, self._poll_paused)
        log.debug("%s: async receive queue full, paused", self.node._label())

    def _poll_paused(self) -> None:
        self._poll = None
        if self.paused and not self.stopped:
            self._on_readable()

    def _maybe_resume(self) -> None:
        if self.paused and not self.stopped and len(self.rx) < self.rx_cap:
            if self._poll is not None:
                self._poll.cancel()
                self._poll = None
            self._start_reading()

    def _on_readable(self) -> None:
        node = self.node
        try:
            while len(self.rx) < self.rx_cap or self.rx_waiters:
                msg = node._rx_c(None)
                if msg is None:
                    break
                self._deliver(self.rx_waiters, self.rx, msg)
            while True:
                ev = node._ev_c(None)
                if ev is None:
                    break
                if not self._deliver(self.ev_waiters, self.ev, ev) and len(self.ev) > self.ev_cap:
                    self.ev.popleft()
                    self.events_dropped += 1
        except ClosedError:
            self._detach()
            return
        except FapError as exc:  # pragma: no cover - fapx_rx/event_get only fail on close
            log.error("%s: async reader failed: %s", node._label(), exc)
            self._fail_waiters(exc)
            return
        if len(self.rx) >= self.rx_cap:
            self._pause()
        elif self.paused:
            self._maybe_resume()

    @staticmethod
    def _deliver(waiters: Deque["asyncio.Future[Any]"], queue: Deque[Any], item: Any) -> bool:
        """Hand item to the first live waiter (True) or queue it (False)."""
        while waiters:
            fut = waiters.popleft()
            if not fut.done():
                fut.set_result(item)
                return True
        queue.append(item)
        return False

    # -- consumers --------------------------------------------------------------
    def _in_loop_thread(self) -> bool:
        return threading.get_ident() == self.thread_id

    def take_rx(self) -> Optional["Message"]:
        """A message already moved to Python, or None (any thread)."""
        try:
            msg = self.rx.popleft()
        except IndexError:
            return None
        if self.paused:
            if self._in_loop_thread():
                self._maybe_resume()
            else:
                try:
                    self.loop.call_soon_threadsafe(self._maybe_resume)
                except RuntimeError:  # the loop is closed
                    pass
        return msg

    def take_event(self) -> Optional["SlaveEvent"]:
        """An event already moved to Python, or None (any thread)."""
        try:
            return self.ev.popleft()
        except IndexError:
            return None

    def rx_queued(self) -> int:
        """Messages moved to Python and not taken yet."""
        return len(self.rx)

    async def _next(self, take: Callable[[], Any], waiters: Deque["asyncio.Future[Any]"],
                    queue: Deque[Any], timeout: Optional[float], what: str) -> Any:
        """``take()``'s item, else wait for the fd reader to hand one to a future in
        ``waiters`` at most ``timeout`` seconds (None: no limit): FapTimeoutError then."""
        timeout = check_timeout(timeout)
        item = take()
        if item is not None:
            return item
        if self.stopped:
            raise self.node._closed_error()
        fut = self.loop.create_future()
        waiters.append(fut)
        timer = None
        if timeout is not None:
            timer = self.loop.call_later(timeout, self._expire, fut,
                                         f"{what}: nothing within {timeout} s")
        try:
            return await fut
        except asyncio.CancelledError:
            # Cancelled after the item was handed over: put it back, lose nothing.
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                queue.appendleft(fut.result())
            raise
        finally:
            if timer is not None:
                timer.cancel()
            if fut in waiters:       # still there after a timeout or a cancel
                waiters.remove(fut)  # (a miss would build a ValueError with repr(fut))

    @staticmethod
    def _expire(fut: "asyncio.Future[Any]", text: str) -> None:
        if not fut.done():
            fut.set_exception(FapTimeoutError(text))

    async def get_rx(self, timeout: Optional[float]) -> "Message":
        """The next message: from the deque, else wait (the fd reader fills it) at most
        ``timeout`` seconds (None: no limit): FapTimeoutError then."""
        got: "Message" = await self._next(self.take_rx, self.rx_waiters, self.rx, timeout, "arecv")
        return got

    async def get_event(self, timeout: Optional[float]) -> "SlaveEvent":
        """The next engine event: from the deque, else wait (the fd reader fills it) at
        most ``timeout`` seconds (None: no limit): FapTimeoutError then."""
        got: "SlaveEvent" = await self._next(self.take_event, self.ev_waiters, self.ev, timeout,
                                             "await_event")
        return got

    # -- shutdown -----------------------------------------------------------------
    def _fail_waiters(self, exc: BaseException) -> None:
        for waiters in (self.rx_waiters, self.ev_waiters):
            while waiters:
                fut = waiters.popleft()
                if not fut.done():
                    try:
                        fut.set_exception(exc)
                    except RuntimeError:  # its loop is closed
                        pass

    def _detach(self) -> None:
        """Unregister the fd and fail the waiters (loop thread, or loop not running)."""
        self.stopped = True
        if self._poll is not None:
            self._poll.cancel()
            self._poll = None
        if self.reading:
            self.reading = False
            if not self.loop.is_closed():
                self.loop.remove_reader(self.fd)
        self._fail_waiters(self.node._closed_error())

    def stop(self) -> None:
        """Detach from the loop before the handle (and its fd) is closed. Idempotent."""
        if self.stopped and not self.reading:
            return
        self.stopped = True
        loop = self.loop
        if self._in_loop_thread() or loop.is_closed() or not loop.is_running():
            self._detach()
            return
        done = threading.Event()

        def detach() -> None:
            self._detach()
            done.set()

        try:
            loop.call_soon_threadsafe(detach)
        except RuntimeError:  # closed meanwhile
            return
        if not done.wait(2.0):  # pragma: no cover - the loop thread is stuck
            log.warning("%s: event loop did not detach the notify fd within 2 s",
                        self.node._label())


class AsyncMessages:
    """``async for msg in node``: ``arecv()`` until the node is closed (a FAP node's and
    a daemon client's)."""

    if TYPE_CHECKING:   # each user defines it
        async def arecv(self, timeout: Optional[float] = None) -> Message: ...

    def __aiter__(self) -> AsyncIterator[Message]:
        """``async for msg in node``: messages until the node is closed."""
        return self._amessages()

    async def _amessages(self) -> AsyncIterator[Message]:
        try:
            while True:
                yield await self.arecv()
        except ClosedError:
            return
