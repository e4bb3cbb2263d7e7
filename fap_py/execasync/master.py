"""The exec async master on a port (the C master engine; sync and asyncio)."""
from __future__ import annotations

import asyncio
import errno
import logging
import os
import threading
import time
from typing import Any, Optional, Tuple, Union

from .. import _trace  # wire bytes on fap_py.wire.exec at DEBUG
from .._handle import NativeHandle
from .._interruptible import open_interruptibly
from .._native import ffi, lib
from .._validate import check_path
from ..errors import ClosedError
from ..rs485 import RS485, port_options  # the line options every fap_py node takes
from .codec import (
    MAX_DATA,
    BytesLike,
    _check_data,
    _check_node,
)
from .daemon import DaemonMaster
from .errors import (
    ExecAsyncError,
    ExecValueError,
    _raise_for,
)
from .node import MasterStats, _reopen, _retries_checked, _stats, _timeout_us

log = logging.getLogger("fap_py.execasync")   # one logger for the package (as before the split)


class _Steps:
    """One :meth:`Master.atransact` driven from the loop's callbacks: ``execMasterStep``
    runs in the port fd's reader callback (and in the timer's, at the attempt's
    deadline), so a reply that comes in several reads (~10 at 115200 on a paced
    link) wakes the task once, when the transaction ends, not once a read. The
    reader is the master's, kept from one transaction to the next
    (:meth:`Master._alisten`); the timer is one per attempt."""

    __slots__ = ("master", "loop", "args", "deadline", "done", "timer", "at")

    def __init__(self, master: "Master", reply: Any, reply_len: Any, deadline: Any) -> None:
        self.master = master
        self.loop = asyncio.get_running_loop()
        self.args = (reply, MAX_DATA, reply_len, deadline)
        self.deadline = deadline
        self.timer: Optional[asyncio.TimerHandle] = None
        self.at: Optional[int] = None        # the C deadline the timer is set for
        self.done: "asyncio.Future[int]" = self.loop.create_future()   # Step's last rc
        self._arm()

    def _arm(self) -> None:
        """The timer for the attempt's deadline (a retry moves it)."""
        at = self.deadline[0]
        if at != self.at:
            if self.timer is not None:
                self.timer.cancel()
            left = max(0.0, at / 1e9 - time.monotonic())   # both CLOCK_MONOTONIC
            self.timer = self.loop.call_later(left, self._expired)
            self.at = at

    def _expired(self) -> None:
        self.at = None                       # (a loop timer may fire a hair early: set anew)
        self.step()

    def step(self) -> None:
        if self.done.done():
            return
        try:
            rc = int(self.master._call(lib.execMasterStep, *self.args))
        except Exception as exc:             # ClosedError: closed from another thread
            self.done.set_exception(exc)
            return
        if rc != lib.EXEC_MASTER_MORE:
            self.done.set_result(rc)
            return
        self._arm()
        if self.master._aport is None:       # the reader was taken (await_readable)
            self.master._alisten(self)

    def fail(self, exc: BaseException) -> None:
        if not self.done.done():
            self.done.set_exception(exc)

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()


class Master(NativeHandle):
    """Exec async master on one port.

    ``timeout`` is per attempt (end of our frame to end of the reply);
    ``retries`` extra attempts repeat the frame with the same sequence
    number. Sequence numbers are kept per node (0, 1..255, 1..).

    Args:
        port: serial device path (or a :class:`~fap_py.vbus.VirtualBus` path), or
            a daemon's ``fapd:///path.sock`` / ``fapd://host:port`` (``fap serve``: the
            same calls, results and exceptions; a :class:`DaemonMaster` is returned).
        baudrate: line speed.
        timeout: seconds per attempt; ``None`` = the C engine's default
            (``execMasterOptionsInit``).
        retries: extra attempts after the first; ``None`` = the C default.
        rs485: :class:`fap_py.RS485` line options, as for FAP nodes
            (``echo_suppression=True`` on a bus that echoes our own bytes).

    Thread-safe; a context manager.
    """

    _kind = "exec async master"

    def __new__(cls, port: Any = None, *args: Any, **kwargs: Any) -> Any:
        from ..serve._url import is_daemon_url

        if cls is Master and is_daemon_url(port):   # fapd://: the bus a daemon owns
            return DaemonMaster(port, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, port: Union[str, "os.PathLike[str]"], baudrate: int = 115200, *,
                 timeout: Optional[float] = None, retries: Optional[int] = None,
                 rs485: Optional[RS485] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None) -> None:
        super().__init__()
        if weight is not None or priority is not None or token is not None:
            raise ExecValueError(f"{port!r}: weight, priority and token are for a fapd:// URL "
                                 "(a bus shared through `fap serve`)")
        self._lock = threading.Lock()        # one transaction at a time
        self._alock: Optional[asyncio.Lock] = None   # the same among atransact tasks
        self._abufs: Optional[Tuple[Any, Any, Any]] = None   # atransact's reply, length, deadline
        self._aport: Optional[Tuple[asyncio.AbstractEventLoop, int, "asyncio.Future[bool]"]] = None
        self._asteps: Optional[_Steps] = None   # the atransact the reader serves
        self._areopened = False              # reopen() since the reader was added
        self._ainflight = 0                  # atransact calls between Begin and their end
        self.path = check_path(port)
        popts = port_options(baudrate, rs485)
        mopts = ffi.new("execMasterOptions *")
        lib.execMasterOptionsInit(mopts)     # C's defaults are the only defaults
        if timeout is not None:
            mopts.reply_timeout_us = self._timeout_us(timeout)
        if retries is not None:
            mopts.retries = self._retries_checked(retries)
        self._retries = int(mopts.retries)
        out = ffi.new("execMaster **")
        raw = os.fsencode(self.path)

        def open_with(cancel_fd: int) -> int:   # a network open: Ctrl-C ends it (mopts.cancel_fd)
            mopts.cancel_fd = cancel_fd
            return int(lib.execMasterOpen(out, raw, popts, mopts))

        _raise_for(open_interruptibly(raw, open_with,
                                      lambda rc: rc == 0 and lib.execMasterClose(out[0])),
                   "open", self.path)
        self._adopt(out[0])
        self._tap = _trace.attach(lib.execMasterSetTrace, self._h, "exec", self.path)
        self._reply = ffi.new("byte[]", MAX_DATA)
        self._reply_len = ffi.new("word *")
        log.info("exec async master on %s", self.path)

    def _label(self) -> str:
        return f"exec async master on {self.path}"

    def _release(self, h: Any) -> None:
        lib.execMasterClose(h)

    def _interrupt(self) -> None:
        # a transact in another thread returns -ECANCELED (ClosedError) at once
        # instead of waiting out its timeout and retries
        h = self._h
        if h is not None:
            lib.execMasterStop(h)

    def _fd(self, h: Any) -> int:
        return int(lib.fap_port_fd(lib.execMasterPort(h)))

    @staticmethod
    def _timeout_us(timeout: Any) -> int:
        return _timeout_us(timeout)

    @staticmethod
    def _retries_checked(retries: Any) -> int:
        return _retries_checked(retries)

    def set_timeout(self, timeout: float, retries: Optional[int] = None) -> None:
        """Change the per-attempt timeout (s) and, if given, the retries."""
        us = self._timeout_us(timeout)
        r = self._retries if retries is None else self._retries_checked(retries)
        with self._lock, self._using() as m:
            _raise_for(lib.execMasterSetTimeout(m, us, r), "set_timeout")
            self._retries = r

    def transact(self, node: int, data: BytesLike = b"") -> bytes:
        """Poll ``node`` (1..254) with ``data``; return its reply.

        Raises :class:`NoReplyError` / :class:`CorruptReplyError` when every
        attempt failed (the next message to that node then carries SeqNo 0).
        """
        _check_node(node)
        payload = _check_data(data)
        self._not_inside_atransact()
        with self._lock, self._using() as m:
            if log.isEnabledFor(logging.DEBUG):
                log.debug("-> node %d seq %d %s", node, lib.execMasterNextSeq(m, node), payload.hex())
            rc = lib.execMasterTransact(m, node, payload, len(payload), self._reply, MAX_DATA,
                                        self._reply_len)
            _raise_for(rc, f"node {node}", self.path)
            reply = bytes(ffi.buffer(self._reply, self._reply_len[0]))
        if log.isEnabledFor(logging.DEBUG):
            log.debug("<- node %d %s", node, reply.hex())
        return reply

    def _not_inside_atransact(self) -> None:
        """The blocking calls wait in C for an atransact in flight; in that
        atransact's own loop thread this would never end: refuse."""
        if not self._ainflight:
            return
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return                           # another thread: waiting is fine
        raise ExecAsyncError(f"{self._label()}: an atransact is in flight in this event loop; "
                             "use atransact/abroadcast there")

    async def atransact(self, node: int, data: BytesLike = b"") -> bytes:
        """``await``-able :meth:`transact`, driven by the running asyncio loop.

        The C engine's non-blocking steps (``execMasterBegin`` /
        ``execMasterStep``: the same sequence numbers, retries, trace hook
        and stats as :meth:`transact`) run in the loop's thread, each step
        when the port fd turns readable (one ``loop.add_reader`` for the
        whole transaction) or the attempt's deadline passes (a loop timer);
        the task waits once, for the transaction's end. No worker thread. Calls on one master are serialised; different masters
        run concurrently.
        Cancelling ends the transaction as a failure (the next message to
        ``node`` carries SeqNo 0) and leaves the master usable; a close()
        from another task or thread raises :class:`~fap_py.errors.ClosedError`.
        """
        _check_node(node)
        payload = _check_data(data)
        if self._alock is None:
            self._alock = asyncio.Lock()
        if self._abufs is None:              # one set of buffers: used under _alock only
            self._abufs = (ffi.new("byte[]", MAX_DATA), ffi.new("word *"), ffi.new("int64_t *"))
        reply, reply_len, deadline = self._abufs
        what = f"node {node}"
        async with self._alock:
            log.debug("-> node %d (async) %s", node, payload.hex())
            rc = int(self._call(lib.execMasterBegin, node, payload, len(payload), deadline))
            if rc == -errno.EBUSY:
                raise ExecAsyncError(f"{self._label()}: another atransact is in flight "
                                     "(from another event loop)")
            _raise_for(rc, what, self.path)
            self._ainflight += 1
            over = False
            steps: Optional[_Steps] = None
            try:
                steps = _Steps(self, reply, reply_len, deadline)
                self._alisten(steps)
                rc = await steps.done
                over = True
                _raise_for(rc, what, self.path)
                out = bytes(ffi.buffer(reply, reply_len[0]))
                log.debug("<- node %d (async) %s", node, out.hex())
                return out
            finally:
                self._asteps = None
                if steps is not None:
                    steps.close()
                self._ainflight -= 1
                if not over:                 # cancelled, closed or interrupted mid-way
                    try:
                        self._call(lib.execMasterAbort)
                    except ClosedError:
                        pass

    # The port fd's reader for atransact, kept from one transaction to the next (adding
    # and removing it each time, two epoll_ctl calls and asyncio's bookkeeping, was a
    # tenth of the daemon's time). It is registered with the handle's asyncio waits,
    # so a close() from any thread detaches it and fails the transaction in flight.

    def _alisten(self, steps: _Steps) -> None:
        """Make ``steps`` the transaction the reader serves; add the reader if needed."""
        loop = steps.loop
        port = self._aport
        if port is not None and (port[0] is not loop or self._areopened):
            self._adetach()                  # (a reopened port: another fd, or the number reused)
            port = None
        if port is None:
            self._areopened = False
            fd = int(self._call(self._fd))   # ClosedError once closed
            gone: "asyncio.Future[bool]" = loop.create_future()   # failed by close()
            gone.add_done_callback(self._agone)
            with self._hlock:
                self._async_waits[gone] = fd
            loop.add_reader(fd, self._areadable)
            self._aport = (loop, fd, gone)
        self._asteps = steps

    def _areadable(self) -> None:
        steps = self._asteps
        if steps is not None:
            steps.step()
        else:                                # bytes between transactions: level-triggered,
            self._adetach()                  # it would fire every loop turn; the next Begin drops them

    def _adetach(self) -> None:
        """Remove atransact's reader (from its loop's thread, or with that loop stopped)."""
        port, self._aport = self._aport, None
        if port is None:
            return
        loop, fd, gone = port
        with self._hlock:
            registered = self._async_waits.pop(gone, None) is not None
        if not registered or loop.is_closed():
            return
        try:
            running: Optional[asyncio.AbstractEventLoop] = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop or not loop.is_running():
            loop.remove_reader(fd)
        else:
            loop.call_soon_threadsafe(loop.remove_reader, fd)

    def _agone(self, f: "asyncio.Future[bool]") -> None:
        """close() detached the reader: forget it, fail the transaction in flight."""
        port = self._aport
        if port is not None and port[2] is f:
            self._aport = None
        exc = None if f.cancelled() else f.exception()
        steps = self._asteps
        if steps is not None:
            steps.fail(exc or self._closed_error())

    async def await_readable(self, timeout: Optional[float] = None) -> bool:
        """As :meth:`NativeHandle.await_readable` (atransact's reader, if kept, first
        leaves the fd to it)."""
        self._adetach()
        return await super().await_readable(timeout)

    def fileno(self) -> int:
        """As :meth:`NativeHandle.fileno`; asked in the loop that keeps atransact's
        reader, that reader leaves the fd first (the caller may add its own there)."""
        port = self._aport
        if port is not None and self._asteps is None:
            try:
                here = asyncio.get_running_loop() is port[0]
            except RuntimeError:
                here = False
            if here:
                self._adetach()
        return super().fileno()

    async def abroadcast(self, data: BytesLike = b"") -> None:
        """:meth:`broadcast` from a coroutine, in turn with this master's
        atransact calls (a broadcast only writes: it never waits for a reply)."""
        if self._alock is None:
            self._alock = asyncio.Lock()
        async with self._alock:
            self.broadcast(data)

    def broadcast(self, data: BytesLike = b"") -> None:
        """Send ``data`` to every slave (node 255); nobody answers."""
        payload = _check_data(data)
        self._not_inside_atransact()
        with self._lock, self._using() as m:
            log.debug("-> broadcast %s", payload.hex())
            _raise_for(lib.execMasterBroadcast(m, payload, len(payload)), "broadcast", self.path)

    def next_seq(self, node: int) -> int:
        """The sequence number the next message to ``node`` will carry."""
        _check_node(node, allow_broadcast=True)
        with self._lock:
            return int(self._call(lib.execMasterNextSeq, node))

    def reopen(self) -> None:
        """Open the device again (after it vanished: a USB unplug, say)."""
        with self._lock:
            _reopen(self, lib.execMasterPort)
            self._areopened = True           # atransact's reader: add it again

    def reset_sequence(self) -> None:
        """Start again from sequence number 0 for every node (a master restart)."""
        with self._lock:
            self._call(lib.execMasterResetSequence)

    @property
    def stats(self) -> MasterStats:
        """A snapshot of the counters (``execMasterStats``)."""
        return _stats(self, MasterStats, "execMasterStats *", lib.execMasterGetStats)

    def close(self) -> None:
        """Close the port (waits for a transaction in progress). Idempotent."""
        super().close()


#: this module's exceptions by name, as a daemon's answer names them
