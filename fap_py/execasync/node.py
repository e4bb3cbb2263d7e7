"""What the exec async master and slave share: their counters, stats and reopen."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Type, TypeVar

from .._native import ffi, lib
from .._stats import Counters, stats_from_c
from .._validate import check_int, check_seconds
from .errors import _ERR, _raise_for

# ---- engine ---------------------------------------------------------------------

@dataclass(frozen=True)
class MasterStats(Counters):
    """``execMasterStats``: counters since the master was opened."""

    transactions: int
    replies: int
    failures: int
    retries: int
    timeouts: int
    corrupt: int
    unexpected: int
    broadcasts: int
    tx_frames: int
    rx_frames: int


@dataclass(frozen=True)
class SlaveStats(Counters):
    """``execSlaveStats``: counters since the slave was opened."""

    processed: int
    resent: int
    broadcasts: int
    replies: int
    no_reply: int
    ignored: int
    corrupt: int
    rx_during_tx: int
    collisions: int
    rx_frames: int


_C = TypeVar("_C", bound=Counters)


def _reopen(handle: Any, port_of: Callable[[Any], Any]) -> None:
    """fap_port_reopen on the port under a master's or a slave's handle."""
    with handle._using() as h:
        _raise_for(lib.fap_port_reopen(port_of(h)), "reopen", handle.path)


def _stats(handle: Any, cls: Type[_C], ctype: str, get: Callable[..., Any]) -> _C:
    """A snapshot of a master's or a slave's counters: ``get(handle, ctype)`` as ``cls``."""
    st = ffi.new(ctype)
    handle._call(get, st)
    return stats_from_c(cls, st)


def _timeout_us(timeout: Any) -> int:
    """A master's per-attempt timeout (s, > 0, <= 3600) in whole microseconds, at least 1."""
    t = check_seconds(timeout, "timeout", lo=0.0, lo_open=True, hi=3600.0, **_ERR)
    return max(1, int(round(t * 1e6)))


def _retries_checked(retries: Any) -> int:
    """A master's retries, 0..1000."""
    return check_int(retries, "retries", 0, 1000, **_ERR)
