#!/usr/bin/env python3
"""Overhead of the fap_py binding: the same FAP exchanges through Python and through C.

Both sides drive libfap's engine (one master, one slave) on the SAME virtual
bus, which runs in its own process (``fap bus``) so that each side's CPU
time holds only its own threads: the two C engine threads, plus the Python
interpreter on the Python side.

Modes (each run through fap_py here and through ``bench_fapx_c`` in C):

- ``round-trip``: the master sends SIZE bytes to slave 1, a thread on the
  slave echoes them back, the master waits for the echo. Latency-bound.
- ``stream``: the master queues COUNT messages for slave 1, at most WINDOW
  ahead of the slave thread that receives them. Throughput-bound.
- ``calls``: no wire, a slave nobody polls: ``send()`` into a deep queue +
  ``recv_nowait()`` on an empty one: the pure per-call cost of the binding.
- ``round-trip asyncio`` (Python only): the master awaits ``arecv()``.

Run (needs fap_py installed; builds the C side with meson unless given)::

    python bench/fap_py/bench_fap_py.py [--count 2000] [--sizes 16,1024]
        [--baud 115200] [--c-bench PATH/bench_fapx_c]

With ``--baud`` the bus is paced at that rate (10 bits/byte) and the table
also shows the wire's limit; unpaced, the wire costs nearly nothing and
the numbers show the software alone.

``polls/msg`` is the master's SEND_DATA turns per message over the window:
on the unpaced bus the master polls back to back, so a round trip that
waits for a slow (or descheduled) application thread spans more turns, and
every turn costs both engines wake-ups and CPU (bench/PERFORMANCE.md, "fap_py
per message").
"""
from __future__ import annotations

import argparse
import asyncio
import os
import re
import shutil
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

from fap_py import FapError, FapTimeoutError, Master, Slave

REPO = Path(__file__).resolve().parents[2]
# FAP has no flow control and the unpaced virtual bus drops what a slow
# reader leaves (64 KiB per port): the stream keeps at most WINDOW messages
# between send and receive, so a run measures speed, not scheduling luck.
WINDOW = 32                  # same in bench_fapx_c.c
FRAME_OVERHEAD = 15          # marker 8 + size 2 + msg 1 + dst 1 + src 1 + crc 2


@dataclass
class Result:
    mode: str
    size: int
    api: str
    count: int
    wall_s: float
    cpu_s: float
    received: int = -1     #: stream: messages the slave got (-1: all, by construction)
    polls: int = -1        #: the master's SEND_DATA turns in the window (-1: not counted)

    @property
    def rate(self) -> float:
        """Messages delivered per second."""
        delivered = self.count if self.received < 0 else self.received
        return delivered / self.wall_s if self.wall_s > 0 else float("inf")


# -- the bus ------------------------------------------------------------------

class BusProcess:
    """``fap bus`` in a child process; its port paths."""

    def __init__(self, ports: int, baud: int) -> None:
        cmd = [sys.executable, "-I", "-m", "fap_py", "bus", "--ports", str(ports)]
        if baud:
            cmd += ["--baud", str(baud)]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        self.paths: List[str] = []
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith("port"):
                self.paths.append(line.split()[1])
            elif line.startswith("ready"):
                break
        if len(self.paths) != ports:
            raise SystemExit("fap bus did not start")

    def close(self) -> None:
        self.proc.terminate()
        self.proc.communicate(timeout=10)


# -- the C side ------------------------------------------------------------------

def build_c_bench(build_dir: Path) -> Path:
    """Configure (once) and build bench/fap_py/bench_fapx_c with meson."""
    exe = build_dir / "bench" / "fap_py" / "bench_fapx_c"
    meson = shutil.which("meson") or str(Path(sys.executable).parent / "meson")
    if not (build_dir / "build.ninja").exists():
        subprocess.run([meson, "setup", str(build_dir), str(REPO), "-Dpython=false",
                        "-Dtests=false", "-Dpytest=false", "--buildtype=release"],
                       check=True, stdout=subprocess.DEVNULL)
    subprocess.run([meson, "compile", "-C", str(build_dir), "bench_fapx_c"], check=True,
                   stdout=subprocess.DEVNULL)
    return exe


def run_c(exe: Path, paths: List[str], mode: str, count: int, size: int) -> Result:
    cmode = {"round-trip": "rt", "stream": "stream", "calls": "calls"}[mode]
    proc = subprocess.run([str(exe), paths[0], paths[1], cmode, str(count), str(size)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise SystemExit(f"bench_fapx_c {cmode} failed: {proc.stderr.strip()}")
    f = dict(re.findall(r"(\w+)=(\S+)", proc.stdout))
    return Result(mode, size, "C (fapx)", count, float(f["wall_s"]), float(f["cpu_s"]),
                  int(f["received"]), int(f.get("polls", -1)) if cmode != "calls" else -1)


# -- the Python side -----------------------------------------------------------------

def _pair(paths: List[str]) -> Tuple[Master, Slave]:
    slave = Slave(paths[1], id=1)          # first, so it answers the first query
    master = Master(paths[0], slaves=[1])  # default queue depths, as the C side
    master.wait_active(timeout=10)
    return master, slave


class _SlaveThread(threading.Thread):
    """Receives count messages on the slave (echoing them back if asked).

    Stream mode stops after 2 s of silence: frames an overloaded unpaced bus
    dropped never come (the C side does the same).
    """

    def __init__(self, slave: Slave, count: int, echo: bool) -> None:
        super().__init__(daemon=True)
        self.slave, self.count, self.echo = slave, count, echo
        self.received = 0
        self.progress = threading.Condition()
        self.start()

    def wait_window(self, sent: int) -> None:
        """Block while WINDOW messages are between send and receive (2 s at most)."""
        with self.progress:
            self.progress.wait_for(lambda: sent - self.received < WINDOW, timeout=2.0)

    def run(self) -> None:
        for _ in range(self.count):
            try:
                msg = self.slave.recv(timeout=10 if self.echo else 2)
            except FapTimeoutError:
                if self.echo:
                    raise
                return
            if self.echo:   # the echo first: the count is the bench's, not the round trip's
                self.slave.send(msg.data, msg.source, timeout=None)
            with self.progress:
                self.received += 1
                self.progress.notify()


def _measure(fn: Callable[[], None]) -> Tuple[float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w0, time.process_time() - c0


def run_py(paths: List[str], mode: str, count: int, size: int) -> Result:
    data = bytes((i * 7) & 0xFF for i in range(size))
    if mode == "calls":
        with Slave(paths[1], id=1, tx_queue=count) as s:
            def calls() -> None:
                send, recv_nowait = s.send, s.recv_nowait
                for _ in range(count):
                    send(data, 0)
                    recv_nowait()
            wall, cpu = _measure(calls)
        return Result(mode, size, "Python (fap_py)", count, wall, cpu)
    master, slave = _pair(paths)
    polls0 = master.stats.polls
    try:
        if mode == "round-trip":
            def rt() -> None:
                t = _SlaveThread(slave, count, echo=True)
                for _ in range(count):
                    master.send(data, 1)
                    master.recv(timeout=10)
                t.join()
            wall, cpu = _measure(rt)
            api = "Python (fap_py)"
        elif mode == "round-trip asyncio":
            async def art() -> None:
                for _ in range(count):
                    master.send(data, 1)
                    await master.arecv(timeout=10)

            def run_art() -> None:
                t = _SlaveThread(slave, count, echo=True)
                asyncio.run(art())
                t.join()
            wall, cpu = _measure(run_art)
            api = "Python asyncio"
        else:
            receiver: List[_SlaveThread] = []

            def stream() -> None:
                rx = _SlaveThread(slave, count, echo=False)
                receiver.append(rx)
                for i in range(count):
                    rx.wait_window(i)
                    master.send(data, 1, timeout=None)   # waits for room, as the C side
                receiver[0].join()
            wall, cpu = _measure(stream)
            got = receiver[0].received
            if got < count:
                wall -= 2.0                 # the final 2 s of silence
            return Result(mode, size, "Python (fap_py)", count, wall, cpu, got,
                          master.stats.polls - polls0)
        return Result(mode, size, api, count, wall, cpu, polls=master.stats.polls - polls0)
    finally:
        slave.close()
        master.close()


# -- the one measurement of the target: interleaved pairs ---------------------------

#: The three round-trip runs of one pair (asyncio is Python's too; its ratio is to C).
PAIR_APIS = ("c", "py", "aio")
#: Pairs and round trips per run of the target's measurement: many short pairs
#: (~0.1 s a run) keep both sides of a pair inside one load regime; on this
#: 2-core box at load 4-8, 25 x 300 gave medians within +-0.04 run to run where
#: 11 x 1000 moved by +-0.25 (bench/PERFORMANCE.md).
PAIRS, PAIR_COUNT = 25, 300


def _loadavg() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def paired(exe: Path, paths: List[str], pairs: int = PAIRS, count: int = PAIR_COUNT,
           size: int = 16, baud: int = 0) -> Dict[str, Any]:
    """Round trips through C and fap_py, interleaved on one bus: the measurement of
    issue 24's fap_py target (``python -m bench`` and ``--paired`` both call this).

    One pair is a C run, a fap_py run and a fap_py asyncio run of ``count`` round
    trips each, back to back on the same bus, their order rotated from pair to pair
    (so neither side always runs first after a pause); a load swing between pairs
    moves both sides of a pair alike, so the median of the per-pair ratios holds
    where the rates of whole runs swing (bench/PERFORMANCE.md). Each run also
    reports the master's poll turns per round trip, the unit the unpaced bus
    quantises a round trip in.
    """
    runs: Dict[str, Callable[[], Result]] = {
        "c": lambda: run_c(exe, paths, "round-trip", count, size),
        "py": lambda: run_py(paths, "round-trip", count, size),
        "aio": lambda: run_py(paths, "round-trip asyncio", count, size),
    }
    load_before = _loadavg()
    got: List[Dict[str, Result]] = []
    dropped: List[str] = []
    while len(got) < max(1, pairs) and len(dropped) < max(1, pairs):
        i = len(got) + len(dropped)
        order = PAIR_APIS[i % 3:] + PAIR_APIS[:i % 3]
        try:
            got.append({api: runs[api]() for api in order})
        except (FapError, SystemExit) as e:   # a frame the bus lost: the pair is void
            dropped.append(str(e))
    load_after = _loadavg()
    if not got:
        raise RuntimeError(f"fap_py paired: every pair failed ({dropped[-1]})")

    def col(api: str, fn: Callable[[Result], float]) -> List[float]:
        return [fn(p[api]) for p in got]

    per_pair = [{api: {"rate": p[api].rate, "polls": p[api].polls / p[api].count,
                       "cpu_us": p[api].cpu_s / p[api].count * 1e6} for api in PAIR_APIS}
                for p in got]
    ratio = [p["py"].rate / p["c"].rate for p in got]
    aio_ratio = [p["aio"].rate / p["c"].rate for p in got]
    return {
        "pairs": len(got), "dropped": dropped, "count": count, "size": size, "baud": baud,
        "load_before": load_before, "load_after": load_after,
        "ratio": statistics.median(ratio), "ratio_min": min(ratio), "ratio_max": max(ratio),
        "aio_ratio": statistics.median(aio_ratio),
        "rate": {api: statistics.median(col(api, lambda r: r.rate)) for api in PAIR_APIS},
        "polls": {api: statistics.median(col(api, lambda r: r.polls / r.count))
                  for api in PAIR_APIS},
        "cpu_us": {api: statistics.median(col(api, lambda r: r.cpu_s / r.count * 1e6))
                   for api in PAIR_APIS},
        "per_pair": per_pair,
    }


def paired_report(res: Dict[str, Any]) -> str:
    """The pairs and their medians, for a terminal."""
    names = {"c": "C", "py": "fap_py", "aio": "asyncio"}
    link = f"bus paced at {res['baud']} baud" if res.get("baud") else "unpaced bus"
    L = [f"fap_py vs C round trips ({res['size']} B, {link}): {res['pairs']} interleaved "
         f"pairs of {res['count']} round trips; load average {res['load_before']} -> "
         f"{res['load_after']}",
         f"{'pair':>4}  " + "".join(f"{names[a] + ' /s':>13}{'polls/msg':>10}" for a in PAIR_APIS)
         + f"{'Py/C':>7}"]
    for i, p in enumerate(res["per_pair"], 1):
        L.append(f"{i:>4}  " + "".join(f"{p[a]['rate']:>13,.0f}{p[a]['polls']:>10.2f}"
                                      for a in PAIR_APIS)
                 + f"{p['py']['rate'] / p['c']['rate']:>7.2f}")
    L.append("  med " + "".join(f"{res['rate'][a]:>13,.0f}{res['polls'][a]:>10.2f}"
                               for a in PAIR_APIS) + f"{res['ratio']:>7.2f}")
    for why in res.get("dropped", []):
        L.append(f"  dropped a pair (a frame lost, no echo): {why}")
    L.append(f"median per-pair ratio fap_py/C {res['ratio']:.2f} (range {res['ratio_min']:.2f}"
             f"-{res['ratio_max']:.2f}), asyncio/C {res['aio_ratio']:.2f}; CPU us per round trip "
             + ", ".join(f"{names[a]} {res['cpu_us'][a]:.0f}" for a in PAIR_APIS))
    return "\n".join(L)


# -- report ------------------------------------------------------------------------

def median(repeat: int, run: Callable[[], Result]) -> Result:
    """The run with the median wall time out of ``repeat`` (this machine is shared)."""
    runs = sorted((run() for _ in range(max(1, repeat))), key=lambda r: r.wall_s)
    return runs[len(runs) // 2]


def wire_rate(mode: str, size: int, baud: int) -> Optional[float]:
    """Messages/s the wire allows at baud (10 bits per byte), None if not wire-bound."""
    if mode.startswith("round-trip"):
        # master DATA + SEND_DATA + slave DATA + DATA_DONE
        wire_bytes = 2 * (FRAME_OVERHEAD + size) + 2 * FRAME_OVERHEAD
    elif mode == "stream":
        wire_bytes = FRAME_OVERHEAD + size
    else:
        return None
    return baud / 10.0 / wire_bytes


def print_table(results: List[Result], baud: int) -> None:
    head = (f"{'mode':<20}{'size':>6}  {'API':<17}{'msgs/s':>11}{'us/msg':>10}"
            f"{'CPU us/msg':>12}{'Py/C CPU':>10}{'lost':>7}{'polls/msg':>11}")
    print(head)
    print("-" * len(head))
    base: Dict[Tuple[str, int], Result] = {}
    for r in results:
        if r.api.startswith("C"):
            base[(r.mode, r.size)] = r
    for r in results:
        c = base.get((r.mode.replace(" asyncio", ""), r.size))
        ratio = "" if c is None or r is c or c.cpu_s <= 0 else f"{r.cpu_s / c.cpu_s:.2f}x"
        print(f"{r.mode:<20}{r.size:>6}  {r.api:<17}{r.rate:>11,.0f}"
              f"{r.wall_s / r.count * 1e6:>10.1f}{r.cpu_s / r.count * 1e6:>12.2f}{ratio:>10}"
              f"{r.count - r.received if r.received >= 0 else 0:>7}"
              f"{r.polls / r.count if r.polls >= 0 else float('nan'):>11.2f}")
    wire_baud = baud or 115200
    print(f"\nthe wire's limit at {wire_baud} baud (10 bits/byte"
          f"{'' if baud else '; for reference: this bus is unpaced'}):")
    for mode in ("round-trip", "stream"):
        for size in sorted({r.size for r in results}):
            w = wire_rate(mode, size, wire_baud)
            if w is not None:
                print(f"  {mode:<11} {size:>5} B  {w:>10,.1f} msgs/s")


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, help=f"messages per run (default 2000; --paired {PAIR_COUNT})")
    ap.add_argument("--sizes", default="16,1024", help="message sizes, comma separated")
    ap.add_argument("--baud", type=int, default=0, help="pace the bus at this rate (default unpaced)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs per cell; the table shows the median (default 3)")
    ap.add_argument("--c-bench", type=Path, help="bench_fapx_c executable (default: build it)")
    ap.add_argument("--build-dir", type=Path, default=Path("/tmp/fap_py-bench-build"),
                    help="meson build dir for the C side (default %(default)s)")
    ap.add_argument("--paired", type=int, metavar="PAIRS", nargs="?", const=PAIRS, default=0,
                    help=f"only the target's measurement: PAIRS (default {PAIRS}) interleaved C / "
                         "fap_py / asyncio round-trip runs on one unpaced bus, median per-pair "
                         "ratio (what python -m bench reports)")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    exe = args.c_bench or build_c_bench(args.build_dir)
    count = args.count or 2000
    if args.paired:     # the target's measurement: unpaced unless --baud is given
        bus = BusProcess(2, args.baud)
        count = args.count or PAIR_COUNT
        if args.baud:       # about a second per run at the wire's pace
            count = min(count, max(20, int((wire_rate("round-trip", sizes[0], args.baud) or 100))))
        try:
            print(paired_report(paired(exe, bus.paths, args.paired, count, sizes[0], args.baud)))
        finally:
            bus.close()
        return 0
    bus = BusProcess(2, args.baud)
    results: List[Result] = []
    try:
        cores = os.cpu_count()
        print(f"fap_py binding overhead: {count} messages per run, median of {args.repeat} runs, bus "
              f"{'paced at %d baud' % args.baud if args.baud else 'unpaced'} in its own process, "
              f"{cores} CPUs; CPU = this side's process time (its 2 C engine threads included)\n")
        for size in sizes:
            for mode in ("round-trip", "stream", "calls"):
                n = count if mode != "calls" else max(count, 20000)
                if args.baud and mode != "calls":
                    n = min(n, max(20, int((wire_rate(mode, size, args.baud) or 100) * 2)))
                results.append(median(args.repeat, lambda: run_c(exe, bus.paths, mode, n, size)))
                results.append(median(args.repeat, lambda: run_py(bus.paths, mode, n, size)))
                if mode == "round-trip":
                    results.append(median(args.repeat, lambda: run_py(
                        bus.paths, "round-trip asyncio", n, size)))
    finally:
        bus.close()
    print_table(results, args.baud)
    return 0


if __name__ == "__main__":
    sys.exit(main())
