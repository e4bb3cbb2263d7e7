"""Who uses the bus next: deficit round-robin by wire time. Private, sans-I/O.

Each client has a queue (bounded), a weight and a priority. The highest
priority with work goes first; among equals, clients take turns: at its turn a
client's deficit grows by ``quantum * weight`` seconds of wire time, it runs
transactions while the deficit is positive, and each transaction costs what it
really held the bus (request, turnaround, reply or timeout, retries). A client
whose transactions are long therefore gets fewer of them, and over time every
busy client of one priority holds the bus in proportion to its weight.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, Deque, Dict, List, Optional, Tuple

from ._errors import ClientQueueFullError

#: wire time (s) a weight-1 client may use per turn before the next client's turn
DEFAULT_QUANTUM = 0.005


@dataclass
class Share:
    """One client's place in the scheduler and what it used."""

    key: int
    weight: int = 1
    priority: int = 0
    limit: int = 16
    queue: Deque[Any] = field(default_factory=deque)
    deficit: float = 0.0
    wire_time: float = 0.0        #: seconds of bus time used
    transactions: int = 0


class Scheduler:
    """Deficit round-robin over clients' queues, by wire time."""

    def __init__(self, quantum: float = DEFAULT_QUANTUM) -> None:
        self.quantum = quantum
        self._shares: Dict[int, Share] = {}
        self._rings: Dict[int, List[int]] = {}      # priority -> keys with work, turn order
        self._turn: Optional[int] = None            # the key whose turn is running
        self._queued = 0                            # items in all queues

    def add(self, key: int, weight: int = 1, priority: int = 0, limit: int = 16) -> Share:
        share = Share(key, weight, priority, limit)
        self._shares[key] = share
        return share

    def remove(self, key: int) -> List[Any]:
        """Forget a client; returns the requests it still had queued."""
        share = self._shares.pop(key, None)
        if share is None:
            return []
        ring = self._rings.get(share.priority, [])
        if key in ring:
            ring.remove(key)
        if self._turn == key:
            self._turn = None
        left = list(share.queue)
        share.queue.clear()
        self._queued -= len(left)
        return left

    def share(self, key: int) -> Share:
        return self._shares[key]

    def shares(self) -> List[Share]:
        return list(self._shares.values())

    def push(self, key: int, item: Any) -> None:
        """Queue ``item`` for client ``key``; ClientQueueFullError when its queue is full."""
        share = self._shares[key]
        if len(share.queue) >= share.limit:
            raise ClientQueueFullError(f"queue full: {share.limit} requests already waiting "
                                       "for the bus (the daemon's --queue)")
        share.queue.append(item)
        self._queued += 1
        ring = self._rings.setdefault(share.priority, [])
        if key not in ring:
            ring.append(key)

    def withdraw(self, key: int, match: Any) -> Optional[Any]:
        """Take the first of ``key``'s queued items for which ``match(item)`` holds out of
        its queue (a request its client cancelled before its turn); None if none."""
        share = self._shares.get(key)
        if share is None:
            return None
        for item in share.queue:
            if match(item):
                share.queue.remove(item)
                self._queued -= 1
                return item
        return None

    def pending(self) -> int:
        """Items waiting in all queues."""
        return self._queued

    def next(self) -> Optional[Tuple[int, Any]]:
        """(key, item) to run now, or None when no queue holds work."""
        for prio in sorted((p for p, r in self._rings.items() if r), reverse=True):
            ring = self._rings[prio]
            while ring:
                key = ring[0]
                share = self._shares[key]
                if not share.queue:              # idle: leaves the ring, keeps a debt, no credit
                    ring.pop(0)
                    share.deficit = min(share.deficit, 0.0)
                    if self._turn == key:
                        self._turn = None
                    continue
                if self._turn != key:            # a new turn: this client's quantum
                    self._turn = key
                    share.deficit += self.quantum * share.weight
                if share.deficit > 0:
                    self._queued -= 1
                    return key, share.queue.popleft()
                ring.append(ring.pop(0))         # spent: the next client's turn
                self._turn = None
        return None

    def charge(self, key: int, cost: float) -> None:
        """Account ``cost`` seconds of wire time to ``key``'s last transaction. A client
        whose queue is empty keeps its turn until :meth:`next` looks again: a request it
        queues meanwhile runs on its remaining credit."""
        share = self._shares.get(key)
        if share is None:
            return
        share.deficit -= cost
        share.wire_time += cost
        share.transactions += 1
        ring = self._rings.get(share.priority, [])
        if share.deficit <= 0 and ring and ring[0] == key:
            ring.append(ring.pop(0))
            self._turn = None
