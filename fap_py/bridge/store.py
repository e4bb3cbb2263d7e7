"""The bridge's disk state: the outbox (publications waiting for the broker)
and the set of tx ids already executed. One sqlite3 file per bridge.

The outbox is what makes bus -> broker delivery survive a broker outage:
every publication is written here first and deleted only when the broker
acknowledged it (PUBACK). It is bounded: past ``queue_max`` rows the oldest
rows are dropped (and counted), so a bridge cut off for days cannot fill
the disk. The seen-id set makes a QoS 1 redelivery of a tx run once; it
keeps the newest ``seen_max`` ids.

The write-ahead log is bounded: sqlite's default checkpoints it only past
1000 pages (4 MB), so on a small filesystem the WAL alone could fill the
disk and, holding every page, never let it go. Here the automatic
checkpoint runs every :func:`wal_pages` pages (a sixteenth of the
filesystem, 16..1000 pages), the file is cut back to that size after each
checkpoint (``journal_size_limit``), and it is checkpointed and truncated
to nothing when a write fails with SQLITE_FULL and when the outbox
drains with a WAL larger than that: the space comes back and delivery
resumes by itself.
"""
from __future__ import annotations

import errno
import logging
import os
import sqlite3
import threading
import time
from contextlib import contextmanager
from typing import Iterator, List, Optional, Tuple

from .._closing import Closing
from .._validate import U32, check_bool, check_bytes, check_int, check_path, check_seconds
from ..errors import InvalidTypeError, PortError

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
_YEAR_10000 = 253_402_300_800.0   #: the first Unix time RFC 3339's four-digit year cannot hold


class StoreError(PortError):
    """The state file refused a write or a read (disk full, I/O error): nothing was changed."""


_SEQ_MAX = (1 << 63) - 1   #: sqlite's INTEGER


def _row(topic: object, payload: object, retain: object) -> Tuple[str, bytes, int]:
    """A publication as stored, its fields checked (a wrong type would be stored as is)."""
    if not isinstance(topic, str):
        raise InvalidTypeError(f"topic must be a str, not {type(topic).__name__}")
    return topic, check_bytes(payload, "payload", 0, _SEQ_MAX), int(check_bool(retain, "retain"))


def _seqs(seqs: object) -> List[int]:
    if not isinstance(seqs, (list, tuple)):
        raise InvalidTypeError(f"seqs must be a list of ints, not {type(seqs).__name__}")
    return [check_int(s, "seqs item", 0, _SEQ_MAX) for s in seqs]


WAL_PAGES_MIN = 16      #: the WAL's checkpoint size on the smallest filesystem (pages)
WAL_PAGES_MAX = 1000    #: ... and on a large one: sqlite's own default


def wal_pages(directory: str, page_size: int = 4096) -> int:
    """Pages of WAL between automatic checkpoints for a state file in ``directory``: a
    sixteenth of its filesystem, within WAL_PAGES_MIN..WAL_PAGES_MAX."""
    directory = check_path(directory, "directory")
    page_size = check_int(page_size, "page_size", 512, 65536)
    try:
        st = os.statvfs(directory)
        total = st.f_blocks * st.f_frsize
    except OSError:
        return WAL_PAGES_MAX
    return max(WAL_PAGES_MIN, min(WAL_PAGES_MAX, total // 16 // max(512, page_size)))


def _is_full(exc: sqlite3.Error) -> bool:
    return getattr(exc, "sqlite_errorcode", None) == 13 or "full" in str(exc)


def _errno_of(exc: sqlite3.Error) -> int:
    code = getattr(exc, "sqlite_errorcode", None)
    return errno.ENOSPC if code == 13 or "full" in str(exc) else errno.EIO   # 13: SQLITE_FULL


class Store(Closing):
    """The outbox and the seen-id set in one sqlite3 file (thread-safe)."""

    def __init__(self, path: str, queue_max: int = 100_000, seen_max: int = 10_000) -> None:
        path = check_path(path, "path")
        self.path = path
        self.queue_max = check_int(queue_max, "queue_max", 1, U32)
        self.seen_max = check_int(seen_max, "seen_max", 1, U32)
        self._lock = threading.Lock()
        try:
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            # WAL + NORMAL: a commit is durable against a process crash and cheap
            # (no fsync per row); a power cut may lose the last commits.
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            page = int(self._db.execute("PRAGMA page_size").fetchone()[0])
            self.wal_pages = wal_pages(os.path.dirname(os.path.abspath(path)), page)
            self.wal_limit = self.wal_pages * page   #: bytes the WAL is cut back to
            self._db.execute(f"PRAGMA wal_autocheckpoint={self.wal_pages}")
            self._db.execute(f"PRAGMA journal_size_limit={self.wal_limit}")
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

    @contextmanager
    def _txn(self, what: str) -> Iterator[None]:
        """One transaction under the lock: rolled back and StoreError on any sqlite error."""
        with self._lock:
            try:
                self._db.execute("BEGIN")
                yield
                self._db.execute("COMMIT")
            except sqlite3.Error as exc:
                try:
                    self._db.execute("ROLLBACK")
                except sqlite3.Error:   # no transaction left to roll back
                    pass
                if _is_full(exc):
                    self._truncate_wal()
                raise StoreError(_errno_of(exc), f"bridge state {self.path}: {what}: {exc}") from exc

    # -- outbox ---------------------------------------------------------------
    def put(self, topic: str, payload: bytes, retain: bool = False) -> int:
        """Append a publication; returns its sequence number (never reused)."""
        row = _row(topic, payload, retain)
        with self._txn("append"):
            cur = self._db.execute("INSERT INTO outbox(topic, payload, retain) VALUES (?,?,?)", row)
            rows = self._rows + 1
            if rows > self.queue_max:
                rows -= self._drop_oldest(rows - self.queue_max)
            rowid = cur.lastrowid
        self._rows = rows
        assert rowid is not None, "an INSERT always sets lastrowid"
        return rowid

    def put_many(self, items: List[Tuple[str, bytes, bool]]) -> None:
        """Append several publications in one transaction."""
        if not isinstance(items, list) or not all(isinstance(i, tuple) and len(i) == 3 for i in items):
            raise InvalidTypeError(f"items must be a list of (topic, payload, retain), "
                                   f"not {type(items).__name__}")
        if not items:
            return
        values = [_row(t, p, r) for t, p, r in items]
        with self._txn("append"):
            self._db.executemany("INSERT INTO outbox(topic, payload, retain) VALUES (?,?,?)", values)
            rows = self._rows + len(items)
            if rows > self.queue_max:
                rows -= self._drop_oldest(rows - self.queue_max)
        self._rows = rows

    def next_seq(self) -> int:
        """The sequence number the next :meth:`put` will get."""
        with self._lock:
            row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name='outbox'").fetchone()
            return (int(row[0]) if row else 0) + 1

    def _drop_oldest(self, n: int) -> int:
        """Inside a transaction: drop the ``n`` oldest rows; returns ``n``."""
        self._db.execute("DELETE FROM outbox WHERE seq IN (SELECT seq FROM outbox ORDER BY seq LIMIT ?)", (n,))
        self._db.execute("INSERT OR REPLACE INTO counters(name, value) VALUES ('dropped', ?)",
                         (self.dropped + n,))
        self.dropped += n   # only reached when both statements worked
        log.warning("outbox full (%d rows): dropped the %d oldest publications (%d so far)",
                    self.queue_max, n, self.dropped)
        return n

    def after(self, seq: int, limit: int) -> List[Row]:
        """Up to ``limit`` rows with a sequence number above ``seq``, oldest first."""
        seq, limit = check_int(seq, "seq", 0, _SEQ_MAX), check_int(limit, "limit", 0, _SEQ_MAX)
        with self._lock:
            try:
                rows = self._db.execute("SELECT seq, topic, payload, retain FROM outbox WHERE seq > ? "
                                        "ORDER BY seq LIMIT ?", (seq, limit)).fetchall()
            except sqlite3.Error as exc:
                raise StoreError(_errno_of(exc), f"bridge state {self.path}: read: {exc}") from exc
        return [(int(s), t, bytes(p), bool(r)) for s, t, p, r in rows]

    def delete(self, seqs: List[int]) -> None:
        """Forget acknowledged rows."""
        seqs = _seqs(seqs)
        if not seqs:
            return
        with self._txn("delete"):
            cur = self._db.executemany("DELETE FROM outbox WHERE seq=?", [(q,) for q in seqs])
            gone = max(0, cur.rowcount)
        self._rows -= gone
        if self._rows == 0 and self.wal_size() > self.wal_limit:
            with self._lock:
                self._truncate_wal()

    def wal_size(self) -> int:
        """Bytes of the write-ahead log file now (0 when there is none)."""
        try:
            return os.stat(self.path + "-wal").st_size
        except OSError:
            return 0

    def _truncate_wal(self) -> None:
        """Under the lock, outside a transaction: copy the WAL into the database and cut
        it to nothing (best effort: on a full disk the copy may fail, then it is retried
        at the next failure or drain)."""
        try:
            self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()
        except sqlite3.Error as exc:
            log.debug("bridge state %s: checkpoint: %s", self.path, exc)

    @property
    def pending(self) -> int:
        """Rows not yet acknowledged by the broker."""
        return self._rows

    # -- seen tx ids ----------------------------------------------------------
    def first_time(self, tx_id: str) -> bool:
        """Record ``tx_id``; False if it was recorded before (a redelivery)."""
        if not isinstance(tx_id, str):
            raise InvalidTypeError(f"tx_id must be a str, not {type(tx_id).__name__}")
        with self._lock:
            if self._db.execute("SELECT 1 FROM seen WHERE id=?", (tx_id,)).fetchone():
                return False
        with self._txn("record tx id"):
            self._db.execute("INSERT INTO seen(id) VALUES (?)", (tx_id,))
            rows = self._seen_rows + 1
            if rows > self.seen_max + self.seen_max // 10:   # trim in batches, not per insert
                self._db.execute("DELETE FROM seen WHERE n IN (SELECT n FROM seen ORDER BY n LIMIT ?)",
                                 (rows - self.seen_max,))
                rows = self.seen_max
        self._seen_rows = rows
        return True

    def close(self) -> None:
        with self._lock:
            self._db.close()



def now_iso(t: Optional[float] = None) -> str:
    """UTC timestamp with microseconds, RFC 3339 (``2026-11-24T04:40:00.123456Z``)."""
    t = time.time() if t is None else check_seconds(t, "t", hi=_YEAR_10000 - 1)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1e6):06d}Z"
