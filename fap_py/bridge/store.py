"""The bridge's disk state: the outbox (publications waiting for the broker)
and the set of tx ids already executed. One sqlite3 file per bridge.

The outbox is what makes bus -> broker delivery survive a broker outage:
every publication is written here first and deleted only when the broker
acknowledged it (PUBACK). It is bounded: past ``queue_max`` rows the oldest
rows are dropped (and counted), so a bridge cut off for days cannot fill
the disk. The seen-id set makes a QoS 1 redelivery of a tx run once; it
keeps the newest ``seen_max`` ids.
"""
from __future__ import annotations

import logging
import os
import sqlite3
import threading
import time
from typing import List, Optional, Tuple

from ..errors import PortError

log = logging.getLogger(__name__)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    topic TEXT NOT NULL,
    payload BLOB NOT NULL,
    retain INTEGER NOT NULL
);
CREATE TABLE IF NOT EXISTS seen (
    n INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE
);
CREATE TABLE IF NOT EXISTS counters (
    name TEXT PRIMARY KEY,
    value INTEGER NOT NULL
);
"""

Row = Tuple[int, str, bytes, bool]


class Store:
    """The outbox and the seen-id set in one sqlite3 file (thread-safe)."""

    def __init__(self, path: str, queue_max: int = 100_000, seen_max: int = 10_000) -> None:
        self.path = path
        self.queue_max = queue_max
        self.seen_max = seen_max
        self._lock = threading.Lock()
        try:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            # WAL + NORMAL: a commit is durable against a process crash and cheap
            # (no fsync per row); a power cut may lose the last commits.
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
        except (OSError, sqlite3.Error) as exc:
            raise PortError(getattr(exc, "errno", None) or 5, f"bridge state {path}: {exc}", path) from exc
        self._rows = self._count()
        self._seen_rows = int(self._db.execute("SELECT COUNT(*) FROM seen").fetchone()[0])
        self.dropped = self._counter("dropped")
        if self._rows:
            log.info("outbox %s: %d publications left from before", path, self._rows)

    def _count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM outbox").fetchone()[0])

    def _counter(self, name: str) -> int:
        row = self._db.execute("SELECT value FROM counters WHERE name=?", (name,)).fetchone()
        return int(row[0]) if row else 0

    # -- outbox ---------------------------------------------------------------
    def put(self, topic: str, payload: bytes, retain: bool = False) -> int:
        """Append a publication; returns its sequence number (never reused)."""
        with self._lock:
            cur = self._db.execute("INSERT INTO outbox(topic, payload, retain) VALUES (?,?,?)",
                                   (topic, payload, int(retain)))
            self._rows += 1
            if self._rows > self.queue_max:
                self._drop_oldest(self._rows - self.queue_max)
            rowid = cur.lastrowid
            assert rowid is not None, "an INSERT always sets lastrowid"
            return rowid

    def put_many(self, items: List[Tuple[str, bytes, bool]]) -> None:
        """Append several publications in one transaction."""
        if not items:
            return
        with self._lock:
            self._db.execute("BEGIN")
            self._db.executemany("INSERT INTO outbox(topic, payload, retain) VALUES (?,?,?)",
                                 [(t, p, int(r)) for t, p, r in items])
            self._db.execute("COMMIT")
            self._rows += len(items)
            if self._rows > self.queue_max:
                self._drop_oldest(self._rows - self.queue_max)

    def next_seq(self) -> int:
        """The sequence number the next :meth:`put` will get."""
        with self._lock:
            row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name='outbox'").fetchone()
            return (int(row[0]) if row else 0) + 1

    def _drop_oldest(self, n: int) -> None:
        self._db.execute("DELETE FROM outbox WHERE seq IN (SELECT seq FROM outbox ORDER BY seq LIMIT ?)", (n,))
        self._rows -= n
        self.dropped += n
        self._db.execute("INSERT OR REPLACE INTO counters(name, value) VALUES ('dropped', ?)", (self.dropped,))
        log.warning("outbox full (%d rows): dropped the %d oldest publications (%d so far)",
                    self.queue_max, n, self.dropped)

    def after(self, seq: int, limit: int) -> List[Row]:
        """Up to ``limit`` rows with a sequence number above ``seq``, oldest first."""
        with self._lock:
            rows = self._db.execute("SELECT seq, topic, payload, retain FROM outbox WHERE seq > ? "
                                    "ORDER BY seq LIMIT ?", (seq, limit)).fetchall()
        return [(int(s), t, bytes(p), bool(r)) for s, t, p, r in rows]

    def delete(self, seqs: List[int]) -> None:
        """Forget acknowledged rows."""
        if not seqs:
            return
        with self._lock:
            cur = self._db.executemany("DELETE FROM outbox WHERE seq=?", [(s,) for s in seqs])
            self._rows -= max(0, cur.rowcount)

    @property
    def pending(self) -> int:
        """Rows not yet acknowledged by the broker."""
        return self._rows

    # -- seen tx ids ----------------------------------------------------------
    def first_time(self, tx_id: str) -> bool:
        """Record ``tx_id``; False if it was recorded before (a redelivery)."""
        with self._lock:
            try:
                self._db.execute("INSERT INTO seen(id) VALUES (?)", (tx_id,))
            except sqlite3.IntegrityError:
                return False
            self._seen_rows += 1
            if self._seen_rows > self.seen_max + self.seen_max // 10:   # trim in batches, not per insert
                self._db.execute("DELETE FROM seen WHERE n IN (SELECT n FROM seen ORDER BY n LIMIT ?)",
                                 (self._seen_rows - self.seen_max,))
                self._seen_rows = self.seen_max
            return True

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def now_iso(t: Optional[float] = None) -> str:
    """UTC timestamp with microseconds, RFC 3339 (``2026-11-24T04:40:00.123456Z``)."""
    t = time.time() if t is None else t
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}Z"
