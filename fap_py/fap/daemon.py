"""The FAP master's calls on a bus a daemon owns (``fap serve --protocol fap``)."""
from __future__ import annotations

import asyncio
import logging
import threading
import time
from asyncio import get_running_loop as _running_loop
from typing import Any, AsyncIterator, Iterable, Iterator, List, Optional, Union

from .._daemon_life import DaemonLife
from .._handle import WAIT_SLICE
from .._validate import check_baud
from ..errors import (
    ClosedError,
    FapTimeoutError,
    InvalidTypeError,
    NotMasterError,
    UnknownSlaveError,
)
from ..rs485 import RS485Mode
from .aio import AsyncMessages
from .node import PathLike, _deadline, _int, _payload, _seconds, _slave_id
from .types import (
    MASTER_ID,
    MAX_ID,
    EventKind,
    Message,
    SlaveEvent,
    Stats,
    _new_message,
)

log = logging.getLogger(__name__)


class DaemonFapMaster(DaemonLife, AsyncMessages):
    """The FAP master's calls on a bus a daemon owns (``fap serve --protocol fap
    --slaves IDS``, docs/daemon.md): what ``Master("fapd://...")`` returns.

    :meth:`send` queues a DATA frame on the daemon's engine; every message the slaves
    send and every engine event reach every client of the daemon (:meth:`recv`,
    :meth:`wait_event`). ``slaves`` must be among the daemon's; the slave list, the
    timings and the line are the daemon's (``add_slave`` / ``remove_slave`` are refused).
    ``stats`` are the daemon engine's. ``weight``, ``priority``, ``token`` as for
    :class:`fap_py.execasync.DaemonMaster`. The asyncio forms (``arecv``, ``async for``,
    ``await_event``) wait in the loop's default executor.
    """

    id = MASTER_ID

    def __init__(self, port: PathLike, baudrate: int = 115200, *, slaves: Iterable[int] = (),
                 weight: Optional[int] = None, priority: Optional[int] = None,
                 token: Optional[str] = None, **options: Any) -> None:
        from ..serve._client import Connection

        check_baud(baudrate)
        if isinstance(slaves, (str, bytes)) or not isinstance(slaves, Iterable):
            raise InvalidTypeError("slaves must be an iterable of slave IDs")
        ids = [_slave_id(x) for x in slaves]
        self._conn = Connection(port, protocol="fap", weight=weight, priority=priority, token=token,
                                name="fap master")
        self.path: str = self._conn.url
        self.baudrate: int = int(self._conn.welcome.get("baud") or baudrate)
        self.final_stats: Optional[Stats] = None
        self._rx: List[Message] = []
        self._ev: List[SlaveEvent] = []
        self._waits: dict = {}        # the asyncio waits in the executor, by kind (_await)
        self._lock = threading.Lock()
        served = set(self.slaves)
        missing = sorted(set(ids) - served)
        if missing:
            self.close()
            raise UnknownSlaveError(f"{self.path}: slaves {missing} are not the daemon's "
                                    f"(--slaves {sorted(served)})")

    @property
    def rs485_mode(self) -> RS485Mode:
        """The daemon's direction mode."""
        return RS485Mode[str(self._conn.welcome.get("rs485_mode", "NONE"))]

    def _pull(self, timeout: Optional[float]) -> bool:
        """Take one message of the daemon's into the rx / event queues; False on timeout."""
        ev = self._conn.next_event(timeout)
        if ev is None:
            return False
        kind = ev.get("event")
        with self._lock:
            if kind == "fap_rx":
                self._rx.append(_new_message(int(ev["source"]), bytes.fromhex(ev["data"])))
            elif kind == "fap_event":
                try:
                    self._ev.append(SlaveEvent(EventKind[str(ev["kind"])], int(ev["slave"]), int(ev["time_ns"])))
                except (KeyError, ValueError):
                    pass
        return True

    def _take(self, queue: list, timeout: Optional[float], what: str,
              stop: Optional[threading.Event] = None) -> Any:
        deadline = _deadline(None if timeout is None else _seconds(timeout, "timeout"))
        while True:
            with self._lock:
                if queue:
                    return queue.pop(0)
            if stop is not None and stop.is_set():     # its asyncio caller was cancelled
                raise FapTimeoutError(f"{what}: cancelled")
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                raise FapTimeoutError(f"{what}: nothing within {timeout} s")
            self._pull(WAIT_SLICE if left is None else min(left, WAIT_SLICE))

    async def _await(self, queue: list, timeout: Optional[float], what: str) -> Any:
        """``_take`` in the loop's default executor, losing nothing when cancelled: the
        thread is told to stop (within a slice), and what it took meanwhile goes back to
        the front of ``queue`` before the next wait on it starts (one at a time)."""
        loop = _running_loop()
        prev = self._waits.get(what)
        if prev is not None and not prev.done() and prev.get_loop() is loop:
            await asyncio.wait({prev})           # a cancelled wait's thread puts back first
        stop = threading.Event()
        fut = loop.run_in_executor(None, self._take, queue, timeout, what, stop)
        self._waits[what] = fut
        try:
            return await asyncio.shield(fut)
        except asyncio.CancelledError:
            stop.set()

            def put_back(f: "asyncio.Future[Any]") -> None:
                if not f.cancelled() and f.exception() is None:
                    with self._lock:
                        queue.insert(0, f.result())

            fut.add_done_callback(put_back)
            raise

    def send(self, data: Union[bytes, bytearray, memoryview], to: int,
             timeout: Optional[float] = 0.0) -> None:
        """Queue ``data`` (1..1024 bytes) for slave ``to`` on the daemon's engine."""
        dest = _int(to, "to (a slave ID)", 1, MAX_ID)
        payload = _payload(data)
        if timeout is not None:
            _seconds(timeout, "timeout")
        self._conn.call("send", to=dest, data=payload.hex())

    def flush(self, timeout: Optional[float] = None) -> None:
        """Wait until the daemon's engine has sent everything queued."""
        t = 3600.0 if timeout is None else _seconds(timeout, "timeout")
        self._conn.call("flush", timeout=min(t, 3600.0))

    def recv_nowait(self) -> Optional[Message]:
        while self._pull(0):
            pass
        with self._lock:
            return self._rx.pop(0) if self._rx else None

    def recv(self, timeout: Optional[float] = None) -> Message:
        """The next message a slave sent (FapTimeoutError after ``timeout`` s)."""
        msg: Message = self._take(self._rx, timeout, "recv")
        return msg

    def messages(self, timeout: Optional[float] = None) -> Iterator[Message]:
        try:
            while True:
                yield self.recv(timeout)
        except (FapTimeoutError, ClosedError):
            return

    def __iter__(self) -> Iterator[Message]:
        return self.messages(None)

    def wait_event(self, timeout: Optional[float] = None) -> SlaveEvent:
        ev: SlaveEvent = self._take(self._ev, timeout, "wait_event")
        return ev

    def events(self, timeout: Optional[float] = 0.0) -> Iterator[SlaveEvent]:
        try:
            while True:
                yield self.wait_event(timeout)
        except (FapTimeoutError, ClosedError):
            return

    @property
    def slaves(self) -> List[int]:
        return [int(x) for x in self._conn.call("slaves")["slaves"]]

    @property
    def active_slaves(self) -> List[int]:
        return [int(x) for x in self._conn.call("slaves")["active"]]

    def is_active(self, id: int) -> bool:
        sid = _slave_id(id)
        answer = self._conn.call("slaves")
        if sid not in answer["slaves"]:
            raise UnknownSlaveError(f"is_active: id {sid} is not listed")
        return sid in answer["active"]

    def wait_active(self, ids: Optional[Iterable[int]] = None, timeout: Optional[float] = None) -> None:
        if ids is not None and (isinstance(ids, (str, bytes)) or not isinstance(ids, Iterable)):
            raise InvalidTypeError(f"ids must be an iterable of slave IDs, not {type(ids).__name__}")
        want = None if ids is None else {_slave_id(i) for i in ids}
        deadline = _deadline(None if timeout is None else _seconds(timeout, "timeout"))
        while True:
            answer = self._conn.call("slaves")
            target = set(answer["slaves"]) if want is None else want
            if target <= set(answer["active"]):
                return
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                missing = sorted(target - set(answer["active"]))
                raise FapTimeoutError(f"wait_active: slaves {missing} not active within {timeout} s")
            self._pull(0.02 if left is None else min(left, 0.02))   # events are kept for wait_event

    def add_slave(self, id: int) -> None:
        _slave_id(id)
        raise NotMasterError(f"{self.path}: the daemon owns the slave list (fap serve --slaves)")

    def remove_slave(self, id: int) -> None:
        _slave_id(id)
        raise NotMasterError(f"{self.path}: the daemon owns the slave list (fap serve --slaves)")

    @property
    def stats(self) -> Stats:
        """The daemon engine's counters."""
        return Stats(**self._conn.call("fap_stats")["stats"])

    @property
    def rx_pending(self) -> int:
        while self._pull(0):
            pass
        with self._lock:
            return len(self._rx)

    @property
    def tx_pending(self) -> int:
        return int(self._conn.call("tx_pending")["tx_pending"])

    # asyncio: the blocking waits in the loop's default executor (the client side's one
    # thread per wait; the daemon itself runs without threads)
    async def arecv(self, timeout: Optional[float] = None) -> Message:
        if timeout is not None:
            _seconds(timeout, "timeout")
        msg: Message = await self._await(self._rx, timeout, "recv")
        return msg


    async def await_event(self, timeout: Optional[float] = None) -> SlaveEvent:
        if timeout is not None:
            _seconds(timeout, "timeout")
        ev: SlaveEvent = await self._await(self._ev, timeout, "wait_event")
        return ev

    async def aevents(self, timeout: Optional[float] = None) -> AsyncIterator[SlaveEvent]:
        try:
            while True:
                yield await self.await_event(timeout)
        except (FapTimeoutError, ClosedError):
            return
