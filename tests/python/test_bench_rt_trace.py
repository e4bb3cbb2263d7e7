"""bench/rt_trace.py: a turnaround cut into the steps of its path, from a
synthetic ``perf script`` text with known delays (and bench/realtime.py's
profile note built from it)."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import List, Tuple

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from bench import rt_trace  # noqa: E402

BAUD = 115200
T0 = 5_000_000_000.0      # µs: the capture's time 0 on the trace's clock
RELAY, SLAVE, KW1, KW2, OTHER = 10, 20, 30, 31, 99
DELIVERY, KW_BUS, BUS_WAKE = 20, 15, 5


def _line(comm: str, tid: int, t_us: float, ev: str, rest: str) -> str:
    return f"{comm:>16} {tid:6d} {t_us / 1e6:.6f}: {ev}: {rest}\n"


def _exchange(i: int, kw_wait: int) -> Tuple[List[str], Tuple[float, int, int],
                                              Tuple[float, int, int], float]:
    """One poll: the perf lines, the two capture records, the turnaround."""
    start = 1000.0 + 3000.0 * i
    a_end = start + 3 * 10e6 / BAUD
    q1 = round(T0 + a_end) + DELIVERY
    x1 = q1 + kw_wait
    q2 = x1 + 40
    x2 = q2 + KW_BUS
    b_abs = x2 + BUS_WAKE
    wq = "workqueue=events_unbound req_cpu=256 cpu=-1"
    lines = [
        _line("fap-vbus", RELAY, q1, "workqueue:workqueue_queue_work",
              f"work struct=0xffff0000000000a0 function=flush_to_ldisc {wq}"),
        _line("python", OTHER, q1 + 1, "workqueue:workqueue_queue_work",   # another pty
              f"work struct=0xffff0000000000c0 function=flush_to_ldisc {wq}"),
        _line("kworker/u8:1", KW1, x1, "workqueue:workqueue_execute_start",
              "work struct 0xffff0000000000a0: function flush_to_ldisc"),
        _line("kworker/u8:1", KW1, x1 + 4, "sched:sched_wakeup",
              f"comm=python pid={SLAVE} prio=49 target_cpu=001"),
        _line("python", SLAVE, q2, "workqueue:workqueue_queue_work",
              f"work struct=0xffff0000000000b0 function=flush_to_ldisc {wq}"),
        _line("kworker/u8:2", KW2, x2, "workqueue:workqueue_execute_start",
              "work struct 0xffff0000000000b0: function flush_to_ldisc"),
        _line("kworker/u8:2", KW2, x2 + 3, "sched:sched_wakeup",
              f"comm=fap-vbus pid={RELAY} prio=39 target_cpu=000"),
        _line("swapper/0", 0, b_abs, "sched:sched_switch",
              f"prev_comm=swapper/0 prev_pid=0 prev_prio=120 prev_state=R ==> "
              f"next_comm=fap-vbus next_pid={RELAY} next_prio=39"),
    ]
    return lines, (start, 0, 3), (b_abs - T0, 1, 2), b_abs - T0 - a_end


def _trace(waits: List[int]) -> Tuple[rt_trace.Trace, list, List[float]]:
    lines: List[str] = ["garbage that is not an event\n"]
    recs, tas = [], []
    for i, w in enumerate(waits):
        ls, req, ans, ta = _exchange(i, w)
        lines += ls
        recs += [req, ans]
        tas.append(ta)
    return rt_trace.parse(lines, [RELAY, SLAVE]), recs, tas


def test_steps_add_up_to_the_turnaround_and_name_the_slow_hop() -> None:
    waits = [10] * 40 + [1500]
    tr, recs, tas = _trace(waits)
    pairs = rt_trace.pairs(rt_trace.bursts(recs, BAUD))
    assert [round(b - a, 3) for a, b in pairs] == [round(t, 3) for t in tas]
    off = rt_trace.align(tr, SLAVE, RELAY, [b for _, b in pairs], T0 - 3000.0, T0 + 3000.0)
    assert off is not None and off == pytest.approx(T0, abs=1.0)
    rows = rt_trace.attribute(tr, RELAY, SLAVE, pairs, off)
    assert len(rows) == len(waits)
    for r, w in zip(rows, waits):
        assert sum(r[s] for s in rt_trace.STEPS) == pytest.approx(r["turnaround"], abs=0.01)
        assert r["kworker->slave wait"] == pytest.approx(w, abs=1.0)
        assert r["kworker->bus wait"] == pytest.approx(KW_BUS, abs=0.01)
        assert r["bus wake"] == pytest.approx(BUS_WAKE, abs=1.0)
        assert r["bus delivery"] == pytest.approx(DELIVERY, abs=1.0)
    s = rt_trace.summary(rows, len(pairs))
    assert s["top_step"] == "kworker->slave wait" and s["tail_n"] == 1
    assert s["kworker_wait_share_of_tail"] > 0.9


def test_no_alignment_without_the_slave_writes() -> None:
    tr, recs, _ = _trace([10] * 20)
    pairs = rt_trace.pairs(rt_trace.bursts(recs, BAUD))
    assert rt_trace.align(tr, 12345, RELAY, [b for _, b in pairs], T0 - 3000, T0 + 3000) is None
    assert rt_trace.summary([], 5) == {"attributed": 0, "turnarounds": 5}


def test_profile_note_names_the_step_and_a_thread_left_normal() -> None:
    from bench import realtime

    tr, recs, _ = _trace([10] * 40 + [2000])
    pairs = rt_trace.pairs(rt_trace.bursts(recs, BAUD))
    off = rt_trace.align(tr, SLAVE, RELAY, [b for _, b in pairs], T0 - 3000, T0 + 3000)
    assert off is not None
    steps = rt_trace.summary(rt_trace.attribute(tr, RELAY, SLAVE, pairs, off), len(pairs))
    threads = {"bus": ["python:other/0", "fap-vbus:fifo/60"], "slave": ["python:other/0"],
               "master": ["python:fifo/50"]}
    note = realtime.profile_note({"steps": steps, "threads": threads})
    assert "spend most in 'kworker->slave wait'" in note
    assert "NOT real-time: slave" in note
    assert realtime.profile_note(None) == ""
    assert "not attributed" in realtime.profile_note({"steps": {"attributed": 0}})


def test_threads_reads_each_threads_policy() -> None:
    import os
    import threading

    from bench import realtime

    ready, done = threading.Event(), threading.Event()
    tid: List[int] = []

    def idle() -> None:   # SCHED_IDLE needs no privilege
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        tid.append(threading.get_native_id())
        ready.set()
        done.wait(10)

    t = threading.Thread(target=idle)
    t.start()
    try:
        assert ready.wait(10)
        by = {r["tid"]: r for r in realtime.threads(os.getpid())}
        assert by[tid[0]]["policy"] == os.SCHED_IDLE
        assert by[os.getpid()]["policy"] == os.SCHED_OTHER
        probe = {"policies": {"bus": [by[tid[0]]]}}
        assert realtime._policies(probe)["bus"][0].endswith(":idle/0")
    finally:
        done.set()
        t.join()
