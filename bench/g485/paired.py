"""G485 against the bare Python floor, paired: the one G485 measurement of issue 24.

Three clients take turns in short batches (21 rounds by default), each on its own paced virtual bus
(same baud, same pacing): the bare Python client against the canned
responder (``bench_g485.py --serve canned``: no protocol at all, the floor),
the blocking ``G485Master`` and the asyncio ``AsyncG485Master`` against
``fap g485 sim``. One round is one batch of each; a loaded machine slows the
three alike within a round, so the per-round ratios hold where whole-run
rates swing. Reported: the median of the per-round ratios sync/bare and
async/sync, the median rates, client CPU per read, and the load average.

``python -m bench`` calls :func:`targets`; ``python bench/g485/paired.py
[BAUD...]`` (or ``bench_g485.py --paired``, which runs this program) prints
the same measurement (:func:`measure`, :func:`report`).
"""
from __future__ import annotations

import asyncio
import os
import statistics
import sys
import time
from typing import Any, Callable, Dict, List, Optional, Sequence

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

import bench_g485 as g  # noqa: E402  (the clients and servers of bench_g485.py)

REGS = g.REGS
KINDS = ("bare", "sync", "async")


def _loadavg() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def measure(baud: int, paced: bool = True, rounds: int = 21, batch: Optional[int] = None) -> Dict[str, Any]:
    """``rounds`` interleaved batches of the three clients; rates, CPU and ratios per round."""
    from fap_py.g485 import G485Master
    from fap_py.g485.aio import AsyncG485Master
    from fap_py.vbus import VirtualBus

    if batch is None:  # about 0.05-0.1 s per batch at the bus's pace: short, so a load swing
        batch = max(20, min(250, baud // 4000)) if paced else 100  # rarely splits a round
    me = [sys.executable, os.path.join(HERE, "bench_g485.py"), "--baud", str(baud)]
    pace = baud if paced else None
    load_before = _loadavg()
    with VirtualBus(ports=2, baud=pace, seed=1) as gbus, VirtualBus(ports=2, baud=pace, seed=2) as abus, \
            VirtualBus(ports=2, baud=pace, seed=3) as bbus:
        sims = [g.start_server([sys.executable, "-m", "fap_py", "g485", "sim", "--address", "1", "--baud",
                                str(baud), "--port", bus.paths[1]]) for bus in (gbus, abus)]
        canned = g.start_server(me + ["--serve", "canned", bbus.paths[1]])
        loop = asyncio.new_event_loop()
        try:
            master = G485Master(gbus.paths[0], baud, timeout=0.5, check="none")
            amaster = AsyncG485Master(abus.paths[0], baud, timeout=0.5, check="none")
            bare, bare_close, _ = g.bare_client(bbus.paths[0], spin=False)

            def sync_batch() -> None:
                for _ in range(batch):
                    master.read(1, 1, REGS)

            async def async_reads() -> None:
                for _ in range(batch):
                    await amaster.read(1, 1, REGS)

            def bare_batch() -> None:
                for _ in range(batch):
                    bare()

            fns: Dict[str, Callable[[], None]] = {
                "bare": bare_batch, "sync": sync_batch,
                "async": lambda: loop.run_until_complete(async_reads())}
            for fn in fns.values():
                fn()  # warm up (the simulators may still be opening their ports: a retry is fine)
            rates: Dict[str, List[float]] = {k: [] for k in KINDS}
            cpus: Dict[str, List[float]] = {k: [] for k in KINDS}
            dropped = 0
            while len(rates["bare"]) < rounds and dropped < rounds:
                got: Dict[str, Any] = {}
                try:
                    for k in KINDS:
                        c0, t0 = time.thread_time(), time.perf_counter()
                        fns[k]()
                        dt, dc = time.perf_counter() - t0, time.thread_time() - c0
                        got[k] = (batch / dt, dc / batch * 1e6)
                except Exception:  # a read that failed spoils the round for everyone
                    dropped += 1
                    continue
                for k in KINDS:
                    rates[k].append(got[k][0])
                    cpus[k].append(got[k][1])
            loop.run_until_complete(amaster.aclose())
            master.close()
            bare_close()
        finally:
            loop.close()
            for proc in sims + [canned]:
                proc.terminate()
                proc.wait(5)
                if proc.stdout:
                    proc.stdout.close()
    if not rates["bare"]:
        raise RuntimeError(f"g485 paired at {baud}: every round failed")
    return {
        "baud": baud, "paced": paced, "batch": batch, "rounds": len(rates["bare"]), "dropped": dropped,
        "load_before": load_before, "load_after": _loadavg(),
        "rate": {k: statistics.median(v) for k, v in rates.items()},
        "client_us": {k: statistics.median(v) for k, v in cpus.items()},
        "sync_vs_bare": statistics.median(s / b for s, b in zip(rates["sync"], rates["bare"])),
        "async_vs_sync": statistics.median(a / s for a, s in zip(rates["async"], rates["sync"])),
        "sync_vs_bare_rounds": [s / b for s, b in zip(rates["sync"], rates["bare"])],
    }


def report(res: Dict[str, Any]) -> str:
    """Lines for a terminal."""
    link = f"paced at {res['baud']} baud" if res["paced"] else "unpaced"
    lines = [f"G485 paired: {res['rounds']} rounds of {res['batch']} reads each ({res['dropped']} dropped), "
             f"virtual bus {link}, load {res['load_before']} -> {res['load_after']}"]
    for k in KINDS:
        lines.append(f"  {k:6} median {res['rate'][k]:8.0f} reads/s   client CPU {res['client_us'][k]:6.1f} us/read")
    lines.append(f"  sync/bare  median of per-round ratios {res['sync_vs_bare']:.3f}")
    lines.append(f"  async/sync median of per-round ratios {res['async_vs_sync']:.3f}")
    return "\n".join(lines)


def targets(bauds: Sequence[int] = (115200, 1000000), rounds: int = 21,
            results: Optional[Dict[str, Any]] = None) -> List[Any]:
    """The issue-24 G485 targets as :class:`bench.targets.Target` rows (``results``: filled
    with the raw measurements per baud, for results.json)."""
    from bench.targets import Target

    rows = []
    for baud in bauds:
        try:
            res = measure(baud, True, rounds)
        except Exception as exc:  # reported as not measured, with why
            for name, goal, limit in ((f"g485-sync-{baud}", "G485 sync >= 95 % of bare Python reads/s", 95.0),
                                      (f"g485-async-{baud}", "G485 asyncio >= 90 % of sync reads/s", 90.0)):
                rows.append(Target(name, goal, None, limit, True, "%", f"failed: {exc}"))
            continue
        if results is not None:
            results[str(baud)] = res
        note = (f"paced {baud}, {res['rounds']} paired rounds x {res['batch']} reads, medians: bare "
                f"{res['rate']['bare']:.0f}/s, sync {res['rate']['sync']:.0f}/s, async {res['rate']['async']:.0f}/s; "
                f"load {res['load_before']} -> {res['load_after']}")
        rows.append(Target(f"g485-sync-{baud}", "G485 sync >= 95 % of bare Python reads/s",
                           100 * res["sync_vs_bare"], 95.0, True, "%", note))
        rows.append(Target(f"g485-async-{baud}", "G485 asyncio >= 90 % of sync reads/s",
                           100 * res["async_vs_sync"], 90.0, True, "%", note))
    return rows


def main(argv: Optional[List[str]] = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bauds", type=int, nargs="*", default=[115200, 1000000], metavar="BAUD")
    ap.add_argument("--unpaced", action="store_true", help="unpaced virtual buses (default: paced at BAUD)")
    ap.add_argument("--rounds", type=int, default=21, help="interleaved rounds (default 21)")
    ap.add_argument("--batch", type=int, help="reads per batch (default: about 0.05-0.1 s of reads)")
    a = ap.parse_args(argv)
    for b in a.bauds:
        print(report(measure(b, not a.unpaced, a.rounds, a.batch)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
