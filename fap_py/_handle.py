"""One base class for every object that owns a C handle of libfap. Private.

FAP nodes, exec async masters and slaves, mikroC nodes, the virtual bus and
the Port class all own one C object (a ``fapx *``, ``execMaster *``,
``fap_port *`` ...) that must be freed exactly once, never while another
thread is inside a C call on it, and also when the user forgets to close.
:class:`NativeHandle` is that rule, written once:

* ``_adopt(h)`` once the C open succeeded; ``_release(h)`` (the subclass's
  C close) runs once, from :meth:`close`, ``with`` exit or ``__del__``;
* every C call goes through :meth:`_call` (or ``with self._using() as h``),
  which counts the thread in: :meth:`close` first runs ``_interrupt()``
  (wake blocked calls: stop a serve loop, detach asyncio readers), then
  waits until no thread is inside, then frees;
* calls after close raise :class:`~fap_py.errors.ClosedError`;
* :meth:`wait_readable` / :meth:`await_readable` wait on the handle's fd
  (``_fd()``) with ``poll`` or ``loop.add_reader``: the one way fap_py
  waits on C without a worker thread.

Blocking C calls wait in slices of :data:`WAIT_SLICE` so that Ctrl-C and a
close() from another thread are noticed within one slice.
"""
from __future__ import annotations

import _thread
import asyncio
import logging
import math
import select
import threading
import time
from contextlib import contextmanager
from typing import Any, Callable, Dict, Iterator, Optional, TypeVar

from .errors import ClosedError

__all__ = ["NativeHandle", "WAIT_SLICE", "slice_ms", "deadline_of"]

log = logging.getLogger(__name__)

#: Longest single wait inside C (seconds): the latency of Ctrl-C and of a
#: close() from another thread while a blocking call waits.
WAIT_SLICE = 0.1

H = TypeVar("H", bound="NativeHandle")


def deadline_of(timeout: Optional[float]) -> Optional[float]:
    """``time.monotonic()`` deadline of an already checked timeout (None = none)."""
    return None if timeout is None else time.monotonic() + timeout


def slice_ms(deadline: Optional[float], longest_ms: Optional[int] = None) -> int:
    """Milliseconds for the next wait inside C: what is left until ``deadline``
    (``time.monotonic()``; None = no deadline), at most ``longest_ms``
    (default :data:`WAIT_SLICE`)."""
    cap = int(WAIT_SLICE * 1000) if longest_ms is None else longest_ms
    if deadline is None:
        return cap
    return max(0, min(cap, math.ceil((deadline - time.monotonic()) * 1000)))


class DeferredSigint:
    """A Ctrl-C that landed inside a C callback on the main thread (the wire-trace
    hook, :mod:`fap_py._trace`): raised there it would end in cffi, which prints and
    drops it. The SIGINT guard sets :attr:`pending` instead; the C call that ran the
    hook returns through :meth:`NativeHandle._call` (or ``_using``), which puts the
    signal back with :func:`redeliver`, so the handler raises in the caller's code."""

    pending = False


def redeliver() -> None:
    """Make a deferred Ctrl-C pending again (the handler then runs in this frame)."""
    if DeferredSigint.pending:
        DeferredSigint.pending = False
        _thread.interrupt_main()


class NativeHandle:
    """Lifetime of one C handle: counted use, idempotent close, context manager.

    Subclasses call ``super().__init__()`` first (before anything can fail,
    so ``__del__`` of a half-built object is harmless), open the C object,
    then ``self._adopt(handle)``; they implement :meth:`_release` and, when
    the handle has a pollable fd, :meth:`_fd`.
    """

    #: What the object is, for messages ("exec async master", ...).
    _kind = "handle"

    def __init__(self) -> None:
        self._h: Any = None
        self._hlock = threading.Lock()
        self._idle = threading.Condition(self._hlock)
        # one token per call inside C on _h (see _call: added and removed
        # without the lock, each a single atomic dict operation under the GIL)
        self._inside: Dict[object, None] = {}
        self._closing = False
        self._closer: Optional[int] = None   # the thread running close()
        # await_readable in flight: each future and the fd its loop reads
        self._async_waits: Dict["asyncio.Future[bool]", int] = {}

    # -- to be provided by subclasses ----------------------------------------
    def _release(self, h: Any) -> None:
        """Free the C object (called once, with no thread inside a call)."""
        raise NotImplementedError

    def _interrupt(self) -> None:
        """Wake threads blocked in C on this handle (default: they leave by
        themselves within :data:`WAIT_SLICE`). Runs before the wait."""

    def _fd(self, h: Any) -> int:
        """The fd that turns readable when the handle has input."""
        from .errors import InvalidTypeError
        raise InvalidTypeError(f"{self._kind} has no pollable fd")

    def _label(self) -> str:
        return self._kind

    # -- lifetime ----------------------------------------------------------------
    def _adopt(self, h: Any) -> None:
        """Take ownership of the opened C object."""
        with self._hlock:
            self._h = h

    def _closed_error(self) -> ClosedError:
        return ClosedError(f"{self._label()} is closed")

    def _call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(handle, *args)`` with this call counted in as a user.

        The count is a dict of tokens, one per call inside C, added and
        removed without taking the lock (it ran around every C call of the
        message path; each dict operation is atomic under the GIL, which
        fap_py's abi3 extension always has). The order makes it safe against
        :meth:`close`: a call adds its token *before* it reads ``_closing``,
        close sets ``_closing`` *before* it waits for the dict to empty, so
        either close sees the token and waits, or the call sees ``_closing``
        and never touches the handle. An asynchronous exception
        (KeyboardInterrupt) cannot leave a token behind: the add is inside
        the ``try`` and ``finally`` pops the token if it is there.
        """
        inside = self._inside
        tok = object()
        try:
            inside[tok] = None
            h = self._h
            if self._closing or h is None:
                raise self._closed_error()
            return fn(h, *args)
        finally:   # (one C call, here: a signal may land at a Python function's entry)
            inside.pop(tok, None)
            if self._closing or DeferredSigint.pending:
                self._left()

    def _left(self) -> None:
        """After a counted use: wake a waiting close() (which also looks every
        WAIT_SLICE), put back a deferred Ctrl-C."""
        if self._closing:
            with self._hlock:
                self._idle.notify_all()
        if DeferredSigint.pending:
            redeliver()

    @property
    def _users(self) -> int:
        """Calls inside C on the handle now (for tests and diagnostics)."""
        return len(self._inside)

    @contextmanager
    def _using(self) -> Iterator[Any]:
        """``with self._using() as h:`` the handle, counted in like :meth:`_call`."""
        inside = self._inside
        tok = object()
        try:
            inside[tok] = None
            h = self._h
            if self._closing or h is None:
                raise self._closed_error()
            yield h
        finally:   # (one C call, here: a signal may land at a Python function's entry)
            inside.pop(tok, None)
            if self._closing or DeferredSigint.pending:
                self._left()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called (or the open failed)."""
        return self._closing or self._h is None

    def close(self) -> None:
        """Free the C object. Idempotent and thread-safe; blocked calls in
        other threads end with :class:`~fap_py.errors.ClosedError`."""
        lock = getattr(self, "_hlock", None)
        if lock is None or getattr(self, "_h", None) is None:
            return
        with lock:
            self._closing = True
            while self._closer is not None and self._h is not None:
                self._idle.wait(WAIT_SLICE)   # another thread is closing it
            if self._h is None:
                return
            self._closer = threading.get_ident()
        try:
            self._interrupt()
            self._detach_async_waits()
            with lock:
                while self._inside:           # they leave within WAIT_SLICE
                    self._idle.wait(WAIT_SLICE)
                # Forget the handle first: an interrupt before _release leaks
                # it, one after cannot free it twice.
                h, self._h = self._h, None
            self._release(h)
        finally:
            with lock:
                self._closer = None
                self._idle.notify_all()
            if DeferredSigint.pending:        # a Ctrl-C deferred out of a hook the close ran
                redeliver()
        log.debug("%s closed", self._label())

    def __enter__(self: H) -> H:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def __aenter__(self: H) -> H:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        """Close from a coroutine (the wait for other threads runs in an executor)."""
        self._interrupt()
        await asyncio.get_running_loop().run_in_executor(None, self.close)

    def __del__(self) -> None:  # a forgotten object must not keep its port or thread
        try:
            self.close()
        except Exception:  # pragma: no cover - half-built object, interpreter shutdown
            pass

    # -- waiting on the handle's fd ---------------------------------------------
    def fileno(self) -> int:
        """The fd that turns readable when input is waiting (for select/poll;
        never read it). Valid until close."""
        return int(self._call(self._fd))

    def wait_readable(self, timeout: Optional[float] = None) -> bool:
        """Wait (GIL released, in slices) until :meth:`fileno` is readable;
        False after ``timeout`` seconds (None: no limit)."""
        deadline = deadline_of(_timeout(timeout))
        while True:
            fd = self.fileno()               # raises ClosedError once closed
            p = select.poll()
            p.register(fd, select.POLLIN)
            if p.poll(slice_ms(deadline)):
                return True
            if deadline is not None and time.monotonic() >= deadline:
                return False

    async def await_readable(self, timeout: Optional[float] = None) -> bool:
        """The asyncio form of :meth:`wait_readable`: ``loop.add_reader`` on
        the fd, no thread. False after ``timeout`` seconds; ClosedError when
        the handle is closed meanwhile (from any thread)."""
        timeout = _timeout(timeout)
        loop = asyncio.get_running_loop()
        fd = self.fileno()
        fut: "asyncio.Future[bool]" = loop.create_future()

        def ready() -> None:
            if not fut.done():
                fut.set_result(True)

        loop.add_reader(fd, ready)
        with self._hlock:
            self._async_waits[fut] = fd
        timer = None if timeout is None else loop.call_later(timeout, _expire, fut)
        try:
            return await fut
        finally:
            if timer is not None:
                timer.cancel()
            with self._hlock:
                registered = self._async_waits.pop(fut, None) is not None
            if registered and not loop.is_closed():
                loop.remove_reader(fd)

    def _detach_async_waits(self) -> None:
        """Before the fd is closed: unregister every await_readable, failing it
        with ClosedError (in its loop's thread; waits for that, at most 2 s)."""
        with self._hlock:
            waits, self._async_waits = self._async_waits, {}
        for fut, fd in waits.items():
            loop = fut.get_loop()
            done = threading.Event()

            def detach(fut: "asyncio.Future[bool]" = fut, done: threading.Event = done,
                       loop: asyncio.AbstractEventLoop = loop, fd: int = fd) -> None:
                loop.remove_reader(fd)
                if not fut.done():
                    fut.set_exception(self._closed_error())
                done.set()

            try:
                running = asyncio.get_running_loop()
            except RuntimeError:
                running = None
            if running is loop or not loop.is_running():
                if not loop.is_closed():
                    detach()
                continue
            try:
                loop.call_soon_threadsafe(detach)
            except RuntimeError:  # its loop closed meanwhile
                continue
            if not done.wait(2.0):  # pragma: no cover - that loop's thread is stuck
                log.warning("%s: event loop did not detach within 2 s", self._label())


def _timeout(timeout: Optional[float]) -> Optional[float]:
    """None, or a finite number of seconds >= 0 (the package's one rule)."""
    from ._validate import check_seconds
    return None if timeout is None else check_seconds(timeout, "timeout")


def _expire(fut: "asyncio.Future[bool]") -> None:
    if not fut.done():
        fut.set_result(False)
