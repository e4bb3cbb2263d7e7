"""The node table and the plots' time series, from annotated records.

Protocol-free: each record comes in already tagged with its node and its role
(``req``, ``ans``, ``err`` or None) by :class:`Annotator`, which asks the
protocol's monitor plug-in (``pair``), as the monitor's statistics do. The
counting here is a pure function of the sequence of records, so the table of a
capture's first T seconds is the same whether it was built live or recomputed
from the ring (the slider).

Rules (docs/web.md):
- a request while an earlier one is still unanswered counts a timeout for the
  earlier one's node (a master sends its next request after its timeout), unless
  a bad frame came in its place (counted as that node's error instead);
- a live source's request still unanswered :data:`PENDING_S` seconds (wall time)
  after it came is a timeout too (a quiet bus after a lost reply), taken back if
  its answer still comes before any other frame: the wall time is when the hub
  read a frame, not when it was on the wire, so a reader that fell behind must not
  change the count (the final table is still a function of the records alone);
- a bad frame (CRC, check, garbage ...) while a request is pending is the polled
  node's error, else it is unattributed (node ``"?"``);
- a collision (a virtual-bus capture event) while a request is pending is the
  polled node's collision, else the bus's;
- reply times (end of the request to the start of the answer) are kept for the
  last :data:`REPLY_WINDOW` answers of each node (p50 / p99 over those).
"""
from __future__ import annotations

from collections import deque
from typing import Any, Deque, Dict, List, Optional, Tuple

from ..monitor.core import Record
from ..monitor.decoders import plugin

#: answers per node the reply-time percentiles are taken over
REPLY_WINDOW = 1024
#: a node is "live" when it sent or was sent a frame in the last this many seconds
LIVE_S = 5.0
#: a live request unanswered this long (wall time, seconds) is counted as a timeout
PENDING_S = 1.0
#: points kept per plot series
SERIES_POINTS = 300


def _pct(values: List[float], q: float) -> Optional[float]:
    """Nearest-rank percentile of an ascending list (the monitor's rule), in ms."""
    if not values:
        return None
    k = max(0, min(len(values) - 1, int(round(q / 100.0 * len(values) + 0.5)) - 1))
    return round(values[k] * 1e3, 3)


class Annotator:
    """(node, role) of each record, in order; keeps the pending request's key."""

    def __init__(self) -> None:
        self._pending: Optional[Tuple[Any, Any, Optional[int], bytes]] = None   # node, key, port, raw

    def annotate(self, rec: Record) -> Tuple[Optional[str], Optional[str]]:
        pend = self._pending
        if not rec.ok:
            return (str(pend[0]) if pend else None), "err"
        node, role, key = plugin(rec.protocol).pair(rec.event, pend[1] if pend else None)
        if node is None:
            return None, None
        if role == "ans" and pend is not None and getattr(plugin(rec.protocol), "DIRECTIONLESS", False):
            # a retry repeats the request (same sender, or the same bytes): not its answer
            if (rec.port is not None and pend[2] is not None and rec.port == pend[2]) or \
                    (rec.port is None and bytes(rec.raw) == pend[3]):
                role = "req"
        if role == "req":
            self._pending = (node, key, rec.port, bytes(rec.raw))
        elif role == "ans":
            self._pending = None
        return str(node), role


class _Node:
    __slots__ = ("frames", "requests", "replies", "timeouts", "errors", "collisions",
                 "last_seen", "replies_ms", "answered_last")

    def __init__(self) -> None:
        self.frames = self.requests = self.replies = self.timeouts = self.collisions = 0
        self.errors: Dict[str, int] = {}
        self.last_seen: Optional[float] = None
        self.replies_ms: Deque[float] = deque(maxlen=REPLY_WINDOW)
        self.answered_last: Optional[bool] = None


class NodeTable:
    """Counters per node plus binned series (frames, bytes, reply times) over source time."""

    def __init__(self, baud: int = 0, bin_s: float = 1.0) -> None:
        self.baud = baud
        self.bin_s = bin_s
        self.nodes: Dict[str, _Node] = {}
        self.frames = self.bad = self.bytes = self.collisions = 0
        self.t_last: Optional[float] = None
        self._pending: Optional[List[Any]] = None          # [node, t_end, bad_seen, wall]
        self._expired: Optional[List[Any]] = None          # the pending one expire() closed
        # bins: index -> [frames, bytes, {node: [sum_s, n]}]
        self._bins: Dict[int, List[Any]] = {}

    def _node(self, name: str) -> _Node:
        n = self.nodes.get(name)
        if n is None:
            n = self.nodes[name] = _Node()
        return n

    def _bin(self, t: Optional[float]) -> Optional[List[Any]]:
        if t is None:
            return None
        i = int(t // self.bin_s)
        b = self._bins.get(i)
        if b is None:
            b = self._bins[i] = [0, 0, {}]
            if len(self._bins) > SERIES_POINTS * 2:
                for k in sorted(self._bins)[:SERIES_POINTS]:
                    del self._bins[k]
        return b

    def add(self, rec: Record, node: Optional[str], role: Optional[str], wall: float = 0.0) -> None:
        t = rec.t
        if t is not None:
            self.t_last = max(self.t_last or t, rec.t_end if rec.t_end is not None else t)
        b = self._bin(t)
        n_bytes = len(rec.raw)
        self.bytes += n_bytes
        if b is not None:
            b[0] += 1
            b[1] += n_bytes
        self.frames += 1
        if role == "err":
            self.bad += 1
            reason = rec.error or "?"
            nd = self._node(node if node is not None else "?")
            nd.errors[reason] = nd.errors.get(reason, 0) + 1
            if t is not None:
                nd.last_seen = t
            self._take_back()               # the sequence's rule: this node's error, no timeout
            if self._pending is not None:
                self._pending[2] = True
            return
        if node is None:
            return
        nd = self._node(node)
        nd.frames += 1
        if t is not None:
            nd.last_seen = t
        if role == "req":
            self._expired = None
            self._close_pending()
            nd.requests += 1
            self._pending = [node, rec.t_end, False, wall]
        elif role == "ans":
            nd.replies += 1
            nd.answered_last = True
            if self._expired is not None and self._expired[0] == node:
                self._take_back()                   # expire() was early: it was answered
            pend = self._pending
            if pend is not None and pend[0] == node and pend[1] is not None and t is not None:
                seconds = max(0.0, t - pend[1])
                nd.replies_ms.append(seconds)
                if b is not None:
                    s = b[2].setdefault(node, [0.0, 0])
                    s[0] += seconds
                    s[1] += 1
            self._pending = None

    def _take_back(self) -> None:
        """The request expire() closed was answered (or damaged) after all: pending again."""
        exp = self._expired
        if exp is not None:
            self._node(exp[0]).timeouts -= 1
            self._pending, self._expired = exp, None

    def _close_pending(self) -> None:
        pend = self._pending
        if pend is not None and not pend[2]:
            nd = self._node(pend[0])
            nd.timeouts += 1
            nd.answered_last = False
        self._pending = None

    def count(self, t: Optional[float], n_bytes: int) -> None:
        """A message that is no frame (an MQTT source's): counted in the series only."""
        b = self._bin(t)
        if t is not None:
            self.t_last = max(self.t_last or t, t)
        if b is not None:
            b[0] += 1
            b[1] += n_bytes
        self.frames += 1

    def expire(self, wall: float, after_s: float = PENDING_S) -> None:
        """A pending request older than ``after_s`` (by the ``wall`` clock of :meth:`add`):
        a timeout now."""
        pend = self._pending
        if pend is not None and not pend[2] and wall - pend[3] >= after_s:
            self._close_pending()
            self._expired = pend

    def finish(self) -> None:
        """The recording ended: a request still unanswered timed out."""
        self._close_pending()

    def collision(self, t: Optional[float]) -> None:
        self.collisions += 1
        if self._pending is not None:
            self._node(self._pending[0]).collisions += 1

    def table(self) -> List[Dict[str, Any]]:
        """One row per node (docs/web.md, "node table")."""
        now = self.t_last
        rows = []
        for name in sorted(self.nodes, key=lambda k: (k == "?", int(k) if k.isdigit() else 0, k)):
            n = self.nodes[name]
            r = sorted(n.replies_ms)
            rows.append({
                "node": name, "frames": n.frames, "requests": n.requests, "replies": n.replies,
                "timeouts": n.timeouts, "errors": sum(n.errors.values()), "errors_by_kind": dict(n.errors),
                "collisions": n.collisions, "last_seen": None if n.last_seen is None else round(n.last_seen, 6),
                "reply_p50_ms": _pct(r, 50), "reply_p99_ms": _pct(r, 99),
                "active": n.answered_last, "live": bool(now is not None and n.last_seen is not None
                                                        and now - n.last_seen <= LIVE_S),
            })
        return rows

    def series(self, complete_only: bool = False) -> Dict[str, Any]:
        """The last SERIES_POINTS bins: frames/s, bus load (share of the wire), reply ms per node;
        ``complete_only``: without the newest bin (a live source is still filling it)."""
        keys = sorted(self._bins)
        if complete_only:
            keys = keys[:-1]
        keys = keys[-SERIES_POINTS:]
        cap = self.baud / 10.0 * self.bin_s if self.baud else 0.0
        reply: Dict[str, List[Optional[float]]] = {}
        for j, k in enumerate(keys):
            for node, (s, c) in self._bins[k][2].items():
                reply.setdefault(node, [None] * len(keys))[j] = round(s / c * 1e3, 3)
        return {"bin_s": self.bin_s, "t": [round(k * self.bin_s, 6) for k in keys],
                "fps": [round(self._bins[k][0] / self.bin_s, 3) for k in keys],
                "load": [round(min(1.0, self._bins[k][1] / cap), 4) if cap else None for k in keys],
                "reply_ms": reply}

    def totals(self) -> Dict[str, Any]:
        return {"frames": self.frames, "bad": self.bad, "bytes": self.bytes,
                "collisions": self.collisions, "t_last": self.t_last, "baud": self.baud}


__all__ = ["Annotator", "NodeTable"]
