"""Where a turnaround's microseconds go on the virtual bus (bench/realtime.py's
profile; sans I/O: it reads ``perf script`` text and a capture's turnarounds).

A FAP poll answer crosses, after the master's request has ended on the
paced wire (capture time ``A``):

1. ``bus delivery``: the relay's timer fires at the request's last byte and
   it writes the byte to the slave's pty (``queue_work`` of the pty's
   ``flush_to_ldisc`` item by the relay thread, ``q1``);
2. ``kworker -> slave``: the kernel runs that item on an ``events_unbound``
   kworker (``execute_start``, ``x1``), which wakes the slave's engine
   thread (``sched_wakeup``, ``w1``);
3. ``slave engine``: the engine runs, reads, answers: its write queues the
   work of the bus side of its pty (``q2``);
4. ``kworker -> bus``: a kworker runs it (``x2``) and wakes the relay
   (``w2``);
5. ``bus wake``: the relay runs and timestamps the answer's first byte
   (capture time ``B``).

``turnaround = B - A`` is the sum of the five steps; steps 2 and 4 are each
split into the kworker's wait for a CPU (``queue -> start``) and its run up
to the wake-up. The capture counts from the bus's open; its offset on the
trace's CLOCK_MONOTONIC is found by matching the relay's switch-ins to the
starts of transmissions (the relay timestamps a burst right after its poll
returns).
"""
from __future__ import annotations

import bisect
import re
import statistics
from dataclasses import dataclass, field
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

#: the perf events the profile records (system-wide, CLOCK_MONOTONIC)
EVENTS = ("sched:sched_wakeup", "sched:sched_switch", "workqueue:workqueue_queue_work",
          "workqueue:workqueue_execute_start")
#: ``perf script -F`` fields the parser reads
FIELDS = "comm,tid,time,event,trace"

STEPS = ("bus delivery", "kworker->slave wait", "slave engine", "kworker->bus wait", "bus wake")

_LINE = re.compile(r"^\s*(.*?)\s+(\d+)\s+(\d+\.\d+):\s+(\S+):\s?(.*)$")
_WORK = re.compile(r"work struct[= ]\s*(0x[0-9a-f]+)")


@dataclass
class Trace:
    """The events of one recording that the attribution needs (times in µs)."""

    wakeups: Dict[int, List[Tuple[float, str, int]]] = field(default_factory=dict)
    switch_in: Dict[int, List[float]] = field(default_factory=dict)
    queued: Dict[str, List[Tuple[float, int]]] = field(default_factory=dict)   # work -> (t, by)
    started: Dict[int, List[Tuple[float, str]]] = field(default_factory=dict)  # kworker -> (t, work)
    by_work: Dict[str, List[float]] = field(default_factory=dict)   # work -> start times
    by_queuer: Dict[int, List[Tuple[float, str]]] = field(default_factory=dict)

    def index(self) -> None:
        """Start times per work item, queued items per thread (from
        ``started`` and ``queued``)."""
        self.by_work, self.by_queuer = {}, {}
        for work, qs in self.queued.items():
            for t, by in qs:
                self.by_queuer.setdefault(by, []).append((t, work))
        for lst in self.by_queuer.values():
            lst.sort()
        for runs in self.started.values():
            for t, work in runs:
                self.by_work.setdefault(work, []).append(t)
        for ts in self.by_work.values():
            ts.sort()


def parse(lines: Iterable[str], tids: Sequence[int]) -> Trace:
    """The wake-ups and switch-ins of ``tids`` and every ``flush_to_ldisc``
    work item (the pty delivery work) from ``perf script -F FIELDS`` text."""
    want = set(tids)
    tr = Trace({t: [] for t in want}, {t: [] for t in want})
    for line in lines:
        m = _LINE.match(line)
        if not m:
            continue
        comm, tid_s, t_s, ev, rest = m.groups()
        t = float(t_s) * 1e6
        if ev == "sched:sched_wakeup":
            p = re.search(r"\bpid=(\d+)", rest)
            if p and int(p.group(1)) in want:
                tr.wakeups[int(p.group(1))].append((t, comm, int(tid_s)))
        elif ev == "sched:sched_switch":
            p = re.search(r"next_pid=(\d+)", rest)
            if p and int(p.group(1)) in want:
                tr.switch_in[int(p.group(1))].append(t)
        elif ev.startswith("workqueue:") and "flush_to_ldisc" in rest:
            w = _WORK.search(rest)
            if not w:
                continue
            if ev == "workqueue:workqueue_queue_work":
                tr.queued.setdefault(w.group(1), []).append((t, int(tid_s)))
            elif ev == "workqueue:workqueue_execute_start":
                tr.started.setdefault(int(tid_s), []).append((t, w.group(1)))
    return tr


def _last_before(items: List[Any], t: float) -> Optional[Any]:
    """The last of ``items`` (time-ordered tuples) at or before ``t``."""
    i = bisect.bisect_right(items, t, key=lambda x: x[0]) - 1
    return items[i] if i >= 0 else None


def bursts(records: Iterable[Tuple[float, int, int]], baud: int) -> List[Tuple[float, float, int]]:
    """(start, end, port) of each transmission from capture records (t_us,
    port, n bytes), a sender's back-to-back records merged: the rule of
    ``bench.stats.turnarounds``, which gives only the differences."""
    ct = 10e6 / baud
    tx: List[Tuple[float, float, int]] = []
    for t, port, n in sorted(records):
        end = t + n * ct
        if tx and tx[-1][2] == port and t - tx[-1][1] < ct / 2:
            tx[-1] = (tx[-1][0], end, port)
        else:
            tx.append((t, end, port))
    return tx


def pairs(tx: List[Tuple[float, float, int]]) -> List[Tuple[float, float]]:
    """(end of a port-0 transmission, start of the next one from another
    port): one turnaround each."""
    return [(a[1], b[0]) for a, b in zip(tx, tx[1:]) if a[2] == 0 and b[2] != 0]


def align(tr: Trace, slave: int, relay: int, answers_us: Sequence[float], lo_us: float, hi_us: float,
          window_us: float = 200.0) -> Optional[float]:
    """The trace time of capture time 0, searched in [lo, hi]: the offset
    at which the most answer starts (capture) fall within ``window_us``
    after one of the slave engine's pty writes (``queue_work`` by the
    slave; a few per poll cycle, so a wrong offset matches few)."""
    tr.index()
    writes = [q[0] for q in tr.by_queuer.get(slave, [])]
    if not writes or not answers_us:
        return None
    sample = list(answers_us)[:: max(1, len(answers_us) // 400)]

    def score(off: float) -> int:
        n = 0
        for b in sample:
            i = bisect.bisect_right(writes, b + off) - 1
            n += i >= 0 and b + off - writes[i] <= window_us
        return n

    best, step, lo, hi = lo_us, 20.0, lo_us, hi_us
    while step >= 1.0:
        cands = [lo + k * step for k in range(int((hi - lo) / step) + 1)]
        best = max(cands, key=score)
        lo, hi, step = best - step, best + step, step / 4
    if score(best) < len(sample) * 3 // 4:
        return None
    return _fine(tr, slave, relay, answers_us, best)


def _fine(tr: Trace, slave: int, relay: int, answers_us: Sequence[float], coarse: float) -> float:
    """The offset to a microsecond or two: the relay timestamps an answer
    right after its poll returns, so where a kworker running the slave's
    write woke the relay, the answer's capture time is the relay's switch-in."""
    wakes = [w for w in tr.wakeups.get(relay, []) if w[1].startswith("kworker")]
    sw = tr.switch_in.get(relay, [])
    d = []
    for b in answers_us:
        q2 = _queued_by(tr, slave, b + coarse + 100.0)
        x2 = _started_after(tr, q2[1], q2[0]) if q2 else None
        if x2 is None:
            continue
        i = bisect.bisect_left(wakes, x2, key=lambda w: w[0])
        if i == len(wakes) or wakes[i][0] - x2 > 200.0:
            continue   # the relay was awake already: no anchor
        j = bisect.bisect_left(sw, wakes[i][0])
        if j < len(sw) and sw[j] - wakes[i][0] < 200.0:
            d.append(sw[j] - b)
    return statistics.median(d) if len(d) >= 10 else coarse


def _queued_by(tr: Trace, by: int, before: float) -> Optional[Tuple[float, str]]:
    """The last pty work item ``by`` queued at or before ``before``: (t, work)."""
    return _last_before(tr.by_queuer.get(by, []), before)


def _started_after(tr: Trace, work: str, t: float) -> Optional[float]:
    """When a kworker first started ``work`` at or after ``t``."""
    ts = tr.by_work.get(work, [])
    i = bisect.bisect_left(ts, t)
    return ts[i] if i < len(ts) else None


def attribute(tr: Trace, relay: int, slave: int, pairs: Sequence[Tuple[float, float]],
              offset: float) -> List[Dict[str, float]]:
    """Per turnaround (capture (request end, answer start) in µs) its five
    steps, when the chain of events is complete in the trace (after
    :func:`align`, which indexes ``tr``)."""
    out = []
    for a_end, b_start in pairs:
        A, B = a_end + offset, b_start + offset
        q2 = _queued_by(tr, slave, B)            # the slave's answer write
        if not q2 or q2[0] < A:
            continue
        x2 = _started_after(tr, q2[1], q2[0])
        q1 = _queued_by(tr, relay, q2[0])        # the request's last byte to the slave
        if x2 is None or x2 > B + 1.0 or not q1 or q1[0] < A - 2000.0:
            continue
        x1 = _started_after(tr, q1[1], q1[0])
        if x1 is None or x1 > q2[0]:
            continue
        t1 = max(q1[0], A)   # a byte that found the item pending waits from its own end
        out.append({"turnaround": B - A, "bus delivery": t1 - A,
                    "kworker->slave wait": max(0.0, x1 - t1), "slave engine": q2[0] - max(x1, t1),
                    "kworker->bus wait": x2 - q2[0], "bus wake": B - x2})
    return out


def _pct(v: List[float], q: float) -> float:
    s = sorted(v)
    return s[min(len(s) - 1, int(q * len(s)))]


def summary(rows: List[Dict[str, float]], n_all: int) -> Dict[str, Any]:
    """p50/p99 of each step over all attributed turnarounds, and each step's
    median share of the turnarounds at or above their p99 (the tail)."""
    if not rows:
        return {"attributed": 0, "turnarounds": n_all}
    ta = [r["turnaround"] for r in rows]
    cut = _pct(ta, 0.99)
    tail = [r for r in rows if r["turnaround"] >= cut]
    steps = {s: {"p50": _pct([r[s] for r in rows], .5), "p99": _pct([r[s] for r in rows], .99),
                 "tail_median": statistics.median(r[s] for r in tail)} for s in STEPS}
    kw = ("kworker->slave wait", "kworker->bus wait")
    share = statistics.median(sum(r[k] for k in kw) / r["turnaround"] for r in tail
                              if r["turnaround"] > 0)
    top = max(STEPS, key=lambda s: steps[s]["tail_median"])
    return {"attributed": len(rows), "turnarounds": n_all, "p99": cut, "tail_n": len(tail),
            "tail_turnaround_median": statistics.median(r["turnaround"] for r in tail),
            "steps": steps, "top_step": top, "kworker_wait_share_of_tail": share}
