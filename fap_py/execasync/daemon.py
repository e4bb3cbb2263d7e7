"""The exec async master on a bus a daemon owns (``fap serve --protocol exec``)."""
from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
import threading
from typing import Any, Dict, Optional, Union

from .._daemon_life import DaemonLife
from ..errors import (
    ClosedError,
    FapError,
)
from ..rs485 import RS485, port_options  # the line options every fap_py node takes
from .codec import (
    BytesLike,
    _check_data,
    _check_node,
)
from .errors import (
    CorruptReplyError,
    ExecAsyncError,
    ExecTypeError,
    ExecValueError,
    NoReplyError,
)
from .node import MasterStats, _retries_checked, _timeout_us

log = logging.getLogger("fap_py.execasync")   # one logger for the package (as before the split)


_WIRE_ERRORS = {c.__name__: (lambda e, c=c: c(str(e.get("message", "")))) for c in
                (ExecAsyncError, ExecValueError, ExecTypeError, NoReplyError, CorruptReplyError)}


class DaemonMaster(DaemonLife):
    """An exec async master on a bus a daemon owns (``fap serve``, docs/daemon.md):
    what ``Master("fapd://...")`` returns. The same calls, results and exceptions as
    :class:`Master`; each transaction (with its retries and sequence number) runs on
    the daemon's engine, atomically among its clients. ``weight``, ``priority`` and
    ``token`` override the URL's query (``?weight=3``, ``?token=``, ``$FAP_SERVE_TOKEN``);
    ``baudrate`` and ``rs485`` are the daemon's (given ones are ignored). Thread-safe:
    several threads (or tasks) may each have a transaction queued.
    """

    _kind = "exec async master"

    def __init__(self, port: Union[str, "os.PathLike[str]"], baudrate: int = 115200, *,
                 timeout: Optional[float] = None, retries: Optional[int] = None,
                 rs485: Optional[RS485] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None) -> None:
        from ..serve._client import Connection, PerLoop

        port_options(baudrate, rs485)            # checked as for a device (the daemon's are used)
        self._timeout = None if timeout is None else _timeout_us(timeout) / 1e6
        self._retries = None if retries is None else _retries_checked(retries)
        self._counts: Dict[str, int] = dict.fromkeys((f.name for f in dataclasses.fields(MasterStats)), 0)
        self._clock = threading.Lock()
        self._hello: Dict[str, Any] = {"weight": weight, "priority": priority, "token": token}
        self._conn = Connection(port, protocol="exec", name="exec master", errors=_WIRE_ERRORS,
                                **self._hello)
        self.path = self._conn.url
        self._aconn = PerLoop(self.path, protocol="exec", name="exec master", errors=_WIRE_ERRORS,
                              **self._hello)
        self.closed = False
        log.info("exec async master on %s", self.path)

    def _fields(self, node: int, data: bytes) -> Dict[str, Any]:
        out: Dict[str, Any] = {"node": node, "data": data.hex()}
        if self._timeout is not None:
            out["timeout"] = self._timeout
        if self._retries is not None:
            out["retries"] = self._retries
        return out

    def _add(self, answer: Dict[str, Any]) -> None:
        with self._clock:
            for k, v in (answer.get("stats") or {}).items():
                if k in self._counts and isinstance(v, int):
                    self._counts[k] += v

    def _ask(self, op: str, **fields: Any) -> Dict[str, Any]:
        if self.closed:
            raise ClosedError(f"exec async master on {self.path} is closed")
        try:
            answer = self._conn.call(op, **fields)
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise
        self._add(answer)
        return answer

    async def _aask(self, op: str, **fields: Any) -> Dict[str, Any]:
        if self.closed:
            raise ClosedError(f"exec async master on {self.path} is closed")
        conn = await self._aconn.get()
        try:
            answer = await conn.call(op, **fields)
        except FapError as exc:
            self._add(getattr(exc, "daemon_answer", {}))
            raise
        except asyncio.CancelledError:
            if op == "transact":   # counted as a direct master counts a cancelled one
                self._add({"stats": {"transactions": 1, "failures": 1}})
            raise
        self._add(answer)
        return answer

    def set_timeout(self, timeout: float, retries: Optional[int] = None) -> None:
        """The per-attempt timeout (s) and, if given, the retries of later transactions."""
        self._timeout = _timeout_us(timeout) / 1e6
        if retries is not None:
            self._retries = _retries_checked(retries)

    def transact(self, node: int, data: BytesLike = b"") -> bytes:
        """As :meth:`Master.transact`, through the daemon."""
        _check_node(node)
        payload = _check_data(data)
        return bytes.fromhex(self._ask("transact", **self._fields(node, payload))["data"])

    async def atransact(self, node: int, data: BytesLike = b"") -> bytes:
        """As :meth:`Master.atransact`: an asyncio connection, no thread."""
        _check_node(node)
        payload = _check_data(data)
        return bytes.fromhex((await self._aask("transact", **self._fields(node, payload)))["data"])

    def broadcast(self, data: BytesLike = b"") -> None:
        """As :meth:`Master.broadcast`."""
        self._ask("broadcast", data=_check_data(data).hex())

    async def abroadcast(self, data: BytesLike = b"") -> None:
        """As :meth:`Master.abroadcast`."""
        await self._aask("broadcast", data=_check_data(data).hex())

    def next_seq(self, node: int) -> int:
        """The sequence number the daemon's next message to ``node`` will carry
        (another client may take it first)."""
        _check_node(node, allow_broadcast=True)
        return int(self._ask("next_seq", node=node)["seq"])

    def reopen(self) -> None:
        """Nothing to do: the daemon reopens the device itself (and says so)."""

    def reset_sequence(self) -> None:
        """Refused: the sequence numbers are the daemon's, shared by its clients."""
        raise ExecAsyncError(f"{self.path}: the daemon owns the sequence numbers; "
                             "restart the daemon to reset them")

    @property
    def stats(self) -> MasterStats:
        """This client's share of the engine's counters (what its transactions did)."""
        with self._clock:
            return MasterStats(**self._counts)

    def fileno(self) -> int:
        raise ExecValueError(f"{self.path}: a daemon connection has no port fd")

    def _closed(self) -> None:
        self.closed = True

    def __repr__(self) -> str:
        return f"<DaemonMaster {self.path}{' closed' if self.closed else ''}>"
