"""The FAP master (ID 0) on a port: polls its slaves, runs the ID cycles."""
from __future__ import annotations

import logging
import time
from typing import Any, Iterable, List, Optional

from ..errors import (
    FapTimeoutError,
    InvalidTypeError,
    InvalidValueError,
)
from .daemon import DaemonFapMaster
from .node import Node, PathLike, _deadline, _error, _int, _slave_id, _slice_ms
from .types import (
    MASTER_ID,
    MAX_ID,
    mask_ids,
)

log = logging.getLogger(__name__)


class Master(Node):
    """The FAP master (ID 0): polls its listed slaves, runs the ID cycles.

    Args:
        port: serial device path (e.g. ``/dev/ttyUSB0`` or a
            :class:`~fap_py.vbus.VirtualBus` path).
        baudrate: line speed (any termios rate; the vendor API allows
            9600..115200).
        slaves: slave IDs (1..31) to list at once (see :meth:`add_slave`).
        id_cycle: seconds between ID cycles while a listed slave is
            inactive (default 15).
        id_answer_timeout: QUERY_ID -> ID window, seconds (default 1).
        data_done_timeout: SEND_DATA -> DATA_DONE limit, seconds (default 15).
        send_budget: sending time per turn, seconds (default 10).
        byte_gap: inter-byte gap that abandons a partial frame, seconds
            (default: the longer of 4 character times and 10 ms).
        reopen_interval: retry period after the port vanished (default 0.2).
        rx_queue, tx_queue, event_queue: C queue depths (256, 64, 256).
        rs485: :class:`RS485` line options.

    Raises:
        InvalidValueError / InvalidTypeError: bad arguments.
        PortError: the port could not be opened (``errno``, ``path`` set).
    """

    _mode = 0

    def __new__(cls, port: Any = None, *args: Any, **kwargs: Any) -> Any:
        from ..serve._url import is_daemon_url

        if cls is Master and is_daemon_url(port):   # fapd://: the bus fap serve owns
            return DaemonFapMaster(port, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, port: PathLike, baudrate: int = 115200, *,
                 slaves: Iterable[int] = (), **options: Any) -> None:
        if isinstance(slaves, (str, bytes)) or not isinstance(slaves, Iterable):
            raise InvalidTypeError("slaves must be an iterable of slave IDs")
        ids = [_slave_id(s) for s in slaves]
        if len(set(ids)) != len(ids):
            twice = sorted({i for i in ids if ids.count(i) > 1})
            raise InvalidValueError(f"slaves: ID {', '.join(map(str, twice))} listed twice: {ids}")
        super().__init__(port, baudrate, node_id=MASTER_ID, **options)
        try:
            for sid in ids:
                self.add_slave(sid)
        except BaseException:
            self.close()
            raise

    #: The IDs a master sends to (send()'s fast path; _check_dest says why others fail).
    _dests = frozenset(range(1, MAX_ID + 1))

    def _check_dest(self, to: Any) -> int:
        return _int(to, "to (a slave ID)", 1, MAX_ID)

    def _slave_call(self, fn: Any, id: int, what: str) -> "tuple[int, int]":
        """``fn(handle, id)`` for one slave ID (checked first): (the ID, C's non-negative
        result); a negative result raises the matching error."""
        sid = _slave_id(id)
        code = self._call(fn, sid)
        if code < 0:
            raise _error(code, what, detail=f"id {sid}")
        return sid, code

    def add_slave(self, id: int) -> None:
        """List slave ``id``; it starts inactive and is queried after the current data cycle.

        Raises:
            SlaveExistsError: already listed.
        """
        sid = self._slave_call(self._lib.fapx_add_slave, id, "add_slave")[0]
        log.info("master: slave %d listed", sid)

    def remove_slave(self, id: int) -> None:
        """Stop polling slave ``id``.

        Raises:
            UnknownSlaveError: not listed.
        """
        sid = self._slave_call(self._lib.fapx_remove_slave, id, "remove_slave")[0]
        log.info("master: slave %d removed", sid)

    def is_active(self, id: int) -> bool:
        """Whether listed slave ``id`` answers (UnknownSlaveError if not listed)."""
        return bool(self._slave_call(self._lib.fapx_slave_active, id, "is_active")[1])

    @property
    def slaves(self) -> List[int]:
        """The listed slave IDs, ascending."""
        return mask_ids(self._call(self._lib.fapx_listed_mask))

    @property
    def active_slaves(self) -> List[int]:
        """The listed slaves that answered their last query, ascending."""
        return mask_ids(self._call(self._lib.fapx_active_mask))

    def wait_active(self, ids: Optional[Iterable[int]] = None,
                    timeout: Optional[float] = None) -> None:
        """Wait until every slave in ``ids`` (default: all listed) is active.

        Waits on engine events; the events it consumes are kept and still
        returned by :meth:`wait_event` / :meth:`events` afterwards.

        Raises:
            FapTimeoutError: not all active within ``timeout`` seconds.
        """
        if ids is not None and (isinstance(ids, (str, bytes)) or not isinstance(ids, Iterable)):
            raise InvalidTypeError(f"ids must be an iterable of slave IDs, not {type(ids).__name__}")
        want = None if ids is None else {_slave_id(i) for i in ids}
        deadline = _deadline(timeout)
        while True:
            target = set(self.slaves) if want is None else want
            if target <= set(self.active_slaves):
                return
            ev = self._ev_c(_slice_ms(deadline))
            if ev is not None:
                with self._lock:
                    self._stash.append(ev)
                    del self._stash[:-self._ev_depth]
            elif deadline is not None and time.monotonic() >= deadline:
                missing = sorted(target - set(self.active_slaves))
                raise FapTimeoutError(f"wait_active: slaves {missing} not active within {timeout} s")
