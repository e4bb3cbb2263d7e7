"""Between the source and the browsers: a bounded ring of decoded frames.

The source's thread appends (:meth:`Hub.publish`); it never waits for a browser.
Each browser reads from its own cursor; a browser that fell further behind
than the ring holds gets the frames it missed counted as dropped for it
(``dropped`` events on its stream, shown on the page), never silently skipped.
"""
from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from typing import Any, Dict, Iterable, List, NamedTuple, Optional, Set, Tuple

from ..monitor.core import Record
from ..monitor.output import to_json
from ._nodes import PENDING_S, Annotator, NodeTable

log = logging.getLogger("fap_py.web")


class Entry(NamedTuple):
    seq: int
    rec: Optional[Record]  # None: a message that is no wire frame (an MQTT source's)
    line: str              # exactly `fap monitor --json`'s line of the record (or the message's JSON)
    node: Optional[str]
    role: Optional[str]
    t: Optional[float]     # the record's wire time (a message's time)


class Client:
    """One browser's stream: its cursor, what it lost, its wake-up."""

    def __init__(self, cursor: int) -> None:
        self.cursor = cursor
        self.dropped = 0
        self.event = asyncio.Event()


class Hub:
    """The ring (``capacity`` frames), the node table, the connected clients."""

    def __init__(self, capacity: int = 20000, baud: int = 0, bin_s: float = 1.0) -> None:
        self.capacity = capacity
        self._lock = threading.Lock()
        # a circular list: the entry of seq s at (s - 1) % capacity (O(1) reads from any cursor)
        self._ring: List[Entry] = []
        self._seq = 0
        self._annotator = Annotator()
        self.table = NodeTable(baud, bin_s)
        self.clients: Set[Client] = set()
        self.loop: Optional[asyncio.AbstractEventLoop] = None
        self._wake_pending = False
        self.source_error: Optional[str] = None
        self.source_done = False
        self.dropped_total = 0          # summed over every client
        self.closing = False            # the server stops: every stream ends
        self.nodes_override: Optional[List[Dict[str, Any]]] = None
        #: a live source: an unanswered request is a timeout after this long (None: a recording)
        self.expire_s: Optional[float] = PENDING_S

    # -- the source side (any thread) -----------------------------------------
    def set_baud(self, baud: int, bin_s: Optional[float] = None) -> None:
        with self._lock:
            self.table.baud = baud
            if bin_s is not None:
                self.table.bin_s = bin_s

    def publish(self, recs: Iterable[Record]) -> None:
        """Decoded records, in order; never blocks on a browser."""
        added = False
        wall = time.monotonic()
        with self._lock:
            for rec in recs:
                node, role = self._annotator.annotate(rec)
                self.table.add(rec, node, role, wall)
                self._seq += 1
                line = json.dumps(to_json(rec), separators=(",", ":"))
                self._append(Entry(self._seq, rec, line, node, role, rec.t))
                added = True
        if added:
            self._wake()

    def _append(self, e: Entry) -> None:
        if len(self._ring) < self.capacity:
            self._ring.append(e)
        else:
            self._ring[(e.seq - 1) % self.capacity] = e

    def publish_messages(self, msgs: Iterable[Tuple[Dict[str, Any], Optional[str], Optional[str],
                                                    Optional[float]]]) -> None:
        """Messages that are no wire frames (object, node, role, time): an MQTT source's."""
        added = False
        with self._lock:
            for obj, node, role, t in msgs:
                self._seq += 1
                line = json.dumps(obj, separators=(",", ":"))
                self.table.count(t, len(line))
                self._append(Entry(self._seq, None, line, node, role, t))
                added = True
        if added:
            self._wake()

    def set_nodes(self, rows: List[Dict[str, Any]]) -> None:
        """The node table as the source counts it (an MQTT bridge's stats), instead of ours."""
        with self._lock:
            self.nodes_override = rows

    def collision(self, t: Optional[float]) -> None:
        with self._lock:
            self.table.collision(t)

    def finished(self, error: Optional[str] = None) -> None:
        """The source ended (a capture read to its end, or an error)."""
        with self._lock:
            if self.expire_s is None:           # a recording: its last request is known unanswered
                self.table.finish()
            self.source_done = True
            self.source_error = error
        self._wake()

    def _wake(self) -> None:
        loop = self.loop
        if loop is None or self._wake_pending:
            return
        self._wake_pending = True
        try:
            loop.call_soon_threadsafe(self._wake_clients)
        except RuntimeError:          # the loop closed: nobody to wake
            pass

    def _wake_clients(self) -> None:
        self._wake_pending = False
        for c in self.clients:
            c.event.set()

    # -- the browser side (the event loop) ------------------------------------
    def connect(self, backlog: int) -> Client:
        """A new client that starts ``backlog`` frames back (all the ring: capacity)."""
        with self._lock:
            c = Client(max(self._first(), self._seq + 1 - backlog))
        self.clients.add(c)
        return c

    def _first(self) -> int:
        """The oldest seq the ring holds (the next one when it is empty); under the lock."""
        return self._seq - len(self._ring) + 1

    def disconnect(self, c: Client) -> None:
        self.clients.discard(c)

    def read(self, c: Client, limit: int) -> Tuple[List[Entry], int]:
        """(up to ``limit`` entries from the client's cursor, frames dropped for it now)."""
        with self._lock:
            if not self._ring:
                return [], 0
            first = self._first()
            dropped = 0
            if c.cursor < first:
                dropped = first - c.cursor
                c.cursor = first
            ring, cap = self._ring, self.capacity
            out = [ring[(s - 1) % cap] for s in range(c.cursor, min(self._seq + 1, c.cursor + limit))]
        if out:
            c.cursor = out[-1].seq + 1
        if dropped:
            c.dropped += dropped
            self.dropped_total += dropped
            log.info("a browser fell behind: %d frames dropped for it (%d in all)", dropped, c.dropped)
        return out, dropped

    def window(self, seq0: Optional[int] = None, seq1: Optional[int] = None,
               t0: Optional[float] = None, t1: Optional[float] = None) -> List[Entry]:
        """The ring's entries with seq0 <= seq <= seq1 and t0 <= t <= t1 (None: no bound)."""
        with self._lock:
            ring, cap = self._ring, self.capacity
            lo, hi = self._first(), self._seq
            if seq0 is not None:
                lo = max(lo, seq0)
            if seq1 is not None:
                hi = min(hi, seq1)
            entries = [ring[(s - 1) % cap] for s in range(lo, hi + 1)]
        out = []
        for e in entries:
            if (seq0 is not None and e.seq < seq0) or (seq1 is not None and e.seq > seq1):
                continue
            t = e.t
            if t is not None and ((t0 is not None and t < t0) or (t1 is not None and t > t1)):
                continue
            out.append(e)
        return out

    def snapshot(self) -> Dict[str, Any]:
        """Node table, series and totals (what the page's ``stats`` event carries)."""
        with self._lock:
            if self.expire_s is not None:
                self.table.expire(time.monotonic(), self.expire_s)
            first = self._first() if self._ring else None
            live = self.expire_s is not None and not self.source_done
            nodes = self.nodes_override if self.nodes_override is not None else self.table.table()
            return {"nodes": nodes, "series": self.table.series(complete_only=live),
                    "totals": {**self.table.totals(), "seq": self._seq, "ring_first": first,
                               "ring_capacity": self.capacity, "dropped_total": self.dropped_total,
                               "clients": len(self.clients)},
                    "source": {"done": self.source_done, "error": self.source_error}}

    def table_of(self, entries: List[Entry], baud: int, bin_s: float) -> Dict[str, Any]:
        """A node table recomputed over some entries (a capture's slider window)."""
        t = NodeTable(baud, bin_s)
        for e in entries:
            if e.rec is not None:
                t.add(e.rec, e.node, e.role)
        if entries and self.source_done and entries[-1].seq == self._seq:
            t.finish()                          # the window reaches the recording's end
        return {"nodes": t.table(), "series": t.series(), "totals": t.totals()}

    def tables_until(self, entries: List[Entry], times: List[float], baud: int,
                     bin_s: float) -> List[Dict[str, Any]]:
        """The node table of the entries up to each of ``times`` (ascending): one pass."""
        t = NodeTable(baud, bin_s)
        out: List[Dict[str, Any]] = []
        i = 0
        for until in times:
            while i < len(entries):
                e = entries[i]
                if e.t is not None and e.t > until:
                    break
                if e.rec is not None:
                    t.add(e.rec, e.node, e.role)
                i += 1
            out.append({"until": until, "nodes": t.table(), "series": t.series(), "totals": t.totals()})
        return out


__all__ = ["Client", "Entry", "Hub"]
