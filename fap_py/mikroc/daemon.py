"""The mikroC master on a bus a daemon owns (``fap serve --protocol mikroc``)."""
from __future__ import annotations

import dataclasses
import threading
from typing import Any, List, Optional

from .._daemon_life import DaemonLife
from .._validate import check_timeout
from ..errors import FapError, FapTimeoutError
from ..rs485 import RS485, port_options
from .codec import BROADCAST, DEFAULT_BAUD, Message, _check_address, _check_data
from .errors import _ERRORS, MikrocFrameError, _frame_error
from .node import NodeStats, PathLike

__all__ = ["DaemonMaster"]


#: this module's exceptions by name, as a daemon's answer names them
_WIRE_ERRORS = {c.__name__: (lambda e: _frame_error(int(e.get("code", 0)), e.get("address")))
                for c in [MikrocFrameError, *_ERRORS.values()]}


def _request_fields(address: int, data: bytes, timeout: Optional[float]) -> dict:
    """A request op's fields, checked (the reply window: ``timeout``, None for the daemon's)."""
    _check_address(address)
    fields: dict = {"address": address, "data": _check_data(data).hex()}
    t = check_timeout(timeout)
    if t is not None:
        fields["timeout"] = max(t, 1e-6)
    return fields


class DaemonMaster(DaemonLife):
    """A mikroC master on a bus a daemon owns (``fap serve --protocol mikroc``,
    docs/daemon.md): what ``Master("fapd://...")`` returns.

    :meth:`request` is one atomic transaction on the daemon. :meth:`send` to a slave
    queues that transaction at once (reply window: the daemon's ``--timeout``) and
    :meth:`receive` returns its reply (or raises its error); with no request of ours
    outstanding, ``receive`` raises FapTimeoutError at once (the daemon delivers no
    frame nobody asked for). A broadcast (address 50) is sent, no reply awaited.
    ``weight``, ``priority``, ``token`` as for :class:`fap_py.execasync.DaemonMaster`.
    """

    def __init__(self, port_path: PathLike, baudrate: int = DEFAULT_BAUD, *,
                 rs485: Optional[RS485] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None) -> None:
        from ..serve._client import Connection, PerLoop

        port_options(baudrate, rs485)            # checked as for a device (the daemon's are used)
        self._conn = Connection(port_path, protocol="mikroc", weight=weight, priority=priority,
                                token=token, name="mikroc master", errors=_WIRE_ERRORS)
        self.path = self._conn.url
        self._outstanding: List[Any] = []
        self._olock = threading.Lock()
        self._hello: dict = {"weight": weight, "priority": priority, "token": token}
        self._aconn = PerLoop(self.path, protocol="mikroc", name="mikroc master",
                              errors=_WIRE_ERRORS, **self._hello)
        self._counts = dict.fromkeys((f.name for f in dataclasses.fields(NodeStats)), 0)

    def send(self, address: int, data: bytes = b"") -> None:
        """Send 0..3 bytes to slave ``address``; a reply is awaited by the daemon for
        :meth:`receive` (none for :data:`BROADCAST`)."""
        _check_address(address)
        data = _check_data(data)
        if address == BROADCAST:
            self._add(self._call("send", address=address, data=data.hex()))
            return
        with self._olock:
            self._outstanding.append(self._conn.submit("request", address=address, data=data.hex()))

    def receive(self, timeout: Optional[float] = 1.0) -> Message:
        """The reply to the oldest :meth:`send` still unanswered."""
        t = check_timeout(timeout)
        with self._olock:
            answer = self._outstanding.pop(0) if self._outstanding else None
        if answer is None:
            raise FapTimeoutError(f"{self.path}: no mikroC frame within {timeout} s "
                                  "(no request of ours outstanding on the daemon)")
        try:
            return self._message(answer.result(timeout=None if t is None else max(t, 0) + 5.0))
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise

    def request(self, address: int, data: bytes = b"", timeout: Optional[float] = 1.0) -> Message:
        """``send`` then ``receive`` as one transaction on the daemon."""
        return self._message(self._call("request", **_request_fields(address, data, timeout)))

    async def arequest(self, address: int, data: bytes = b"",
                       timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`request` (an asyncio connection, no thread)."""
        fields = _request_fields(address, data, timeout)
        conn = await self._aconn.get()
        return self._message(await conn.call("request", **fields))

    def _message(self, answer: dict) -> Message:
        self._add(answer)
        return Message(int(answer["address"]), bytes.fromhex(answer["data"]), False)

    def _add(self, answer: dict) -> None:
        with self._olock:
            for k, v in (answer.get("stats") or {}).items():
                if k in self._counts and isinstance(v, int):
                    self._counts[k] += v

    def _call(self, op: str, **fields: Any) -> dict:
        try:
            return self._conn.call(op, **fields)
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise

    @property
    def stats(self) -> NodeStats:
        """This client's share of the daemon engine's counters."""
        with self._olock:
            return NodeStats(**self._counts)
