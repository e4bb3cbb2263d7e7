"""Statistics and probes every bench part shares: medians, percentiles, the
turnarounds of a bus capture, a process's CPU and wake-ups, the load average.

A leaf module: it imports nothing of the bench (the runner, the network rows
and the real-time bench all read captures through :func:`turnarounds`).
"""
from __future__ import annotations

import statistics
from pathlib import Path
from typing import Dict, List, Tuple


def summary(values: List[float]) -> Dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def pct(values: List[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def turnarounds(capture: Path, baud: int) -> List[float]:
    """µs from the end of each client transmission (port 0) to the start of
    the next transmission from a responder (any other port)."""
    from fap_py.vbus import read_capture

    ct = 10e6 / baud
    tx: List[Tuple[float, float, int]] = []      # (start, end, port), merged bursts
    for r in sorted(read_capture(str(capture)).records, key=lambda r: r.t_us):
        end = r.t_us + len(r.data) * ct
        if tx and tx[-1][2] == r.port and r.t_us - tx[-1][1] < ct / 2:
            tx[-1] = (tx[-1][0], end, r.port)
        else:
            tx.append((r.t_us, end, r.port))
    out = []
    for a, b in zip(tx, tx[1:]):
        if a[2] == 0 and b[2] != 0:
            out.append(b[0] - a[1])
    return out


def proc_cpu(pid: int) -> float:
    """CPU seconds of a process's live threads so far, in ns resolution
    (/proc/PID/task/*/schedstat; /proc/PID/stat counts 10 ms ticks)."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            total += int((task / "schedstat").read_text().split()[0])
        except (OSError, ValueError, IndexError):
            pass                    # a thread that just ended
    return total / 1e9


def proc_wakeups(pid: int) -> int:
    """Voluntary context switches of a process's live threads so far."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            for line in (task / "status").read_text().splitlines():
                if line.startswith("voluntary_ctxt_switches:"):
                    total += int(line.split()[1])
        except (OSError, ValueError):
            pass
    return total


def loadavg() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])
