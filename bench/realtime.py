"""The real-time option against CPU hogs (issue 24; docs/realtime.md).

FAP poll cycles at 115200 on the paced virtual bus, master and slave in two
processes (fap_py nodes: the C engine threads do all the I/O), in four
conditions side by side: quiet or with two CPU-bound hog processes, each
without and with the real-time option (nodes ``fifo:50,mlock``, the bus
relay ``fifo:60``). The turnaround (end of the master's request to the start
of the slave's answer) comes from the bus capture, as in ``python -m bench``;
medians over ``rounds`` rounds of each round's p50/p99, the load average
recorded before and after. One more hogs + real-time round runs under perf
and each of its turnarounds is cut into the steps of its path
(bench/rt_trace.py); the verdict's note names the step the tail is in.

    python bench/realtime.py [--rounds 3] [--seconds 5] [--json] [--no-profile] [--idle-hogs]

``targets(...)`` returns the issue's ``Target`` row (p99 <= 1 ms with the
option and the hogs) and the three other conditions as notes.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Dict, List, Optional

ROOT = Path(__file__).resolve().parent.parent
if __name__ == "__main__" and len(sys.argv) > 1 and sys.argv[1] == "_node":
    # a node process: the installed fap_py, never the checkout or bench/fap_py
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() not in (ROOT, ROOT / "bench")]
else:
    sys.path.insert(0, str(ROOT))
    from bench import rt_trace, use_installed_fap_py
    from bench.stats import pct, turnarounds  # one capture reader
    from bench.targets import Target
    use_installed_fap_py()

BAUD = 115200
NODE_RT = "fifo:50,mlock"   #: the engines' I/O threads
BUS_RT = "fifo:60"          #: the relay paces the wire: above the nodes
LIMIT_US = 1000.0


def node_main(role: str, path: str, spec: str) -> int:
    """One FAP node until stdin closes (the bench's child process)."""
    from fap_py import RS485, Master, RS485Mode, Slave

    rs = RS485(mode=RS485Mode.NONE, realtime=spec or None)
    # bench_wire's paced timing: a loaded machine can stall a frame past 10 ms
    timing: Dict[str, Any] = dict(byte_gap=0.05, send_budget=1.0)
    node = (Master(path, BAUD, slaves=[1], id_cycle=1.0, rs485=rs, **timing) if role == "master"
            else Slave(path, BAUD, id=1, rs485=rs, **timing))
    with node:
        print("ready", flush=True)
        sys.stdin.read()
    return 0


def _spawn(args: List[str]) -> "subprocess.Popen[str]":
    p = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "_node", *args],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                         cwd=tempfile.gettempdir())
    assert p.stdout is not None
    if p.stdout.readline().strip() != "ready":
        p.kill()
        raise RuntimeError(f"node {args[0]} did not start (exit {p.wait()})")
    return p


def _stop(p: "subprocess.Popen[str]") -> None:
    if p.stdin:
        p.stdin.close()
    try:
        p.wait(10)
    except subprocess.TimeoutExpired:
        p.kill()
        p.wait()


def threads(pid: int) -> List[Dict[str, Any]]:
    """Every thread of ``pid``: tid, name, policy (0 other, 1 fifo, 2 rr)
    and real-time priority, from /proc (what the option really gave)."""
    out = []
    for task in sorted(Path(f"/proc/{pid}/task").iterdir(), key=lambda p: int(p.name)):
        try:
            stat = (task / "stat").read_text()
            comm = (task / "comm").read_text().strip()
        except OSError:
            continue   # the thread ended
        f = stat.rsplit(")", 1)[1].split()
        out.append({"tid": int(task.name), "comm": comm, "policy": int(f[38]),
                    "rt_priority": int(f[37])})
    return out


HOG = "while True: pass"
#: the same hog at SCHED_IDLE: what a user can do with their own batch work
IDLE_HOG = "import os; os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))\n" + HOG


def one_round(realtime: bool, hogs: int, seconds: float, tmp: Path,
              probe: Optional[Dict[str, Any]] = None, hog: str = HOG) -> Dict[str, Any]:
    """One run: bus (+capture), slave, master, ``hogs`` busy loops; turnarounds.
    With ``probe`` (a dict), fills it with the threads of the bus, slave and
    master processes, the capture's records and the CLOCK_MONOTONIC window
    (µs) holding the capture's time 0 (and, at the window's end, the threads
    again as ``policies``), then calls ``probe["on_ready"](probe)``
    if there is one, before the measured window."""
    from fap_py.vbus import VirtualBus, read_capture

    cap = tmp / f"rt-{int(realtime)}-{hogs}-{time.monotonic_ns()}.cap"
    hog_procs = [subprocess.Popen([sys.executable, "-c", hog])
                 for _ in range(hogs)]
    try:
        t_lo = time.monotonic_ns() / 1e3
        with VirtualBus(ports=2, baud=BAUD, seed=1, capture=str(cap),
                        realtime=BUS_RT if realtime else None) as bus:
            t_hi = time.monotonic_ns() / 1e3
            spec = NODE_RT if realtime else ""
            slave = _spawn(["slave", bus.paths[1], spec])
            try:
                master = _spawn(["master", bus.paths[0], spec])
                if probe is not None:
                    probe.update(t0_window=(t_lo, t_hi), bus=threads(os.getpid()),
                                 slave=threads(slave.pid), master=threads(master.pid))
                    if "on_ready" in probe:
                        probe["on_ready"](probe)
                time.sleep(seconds)   # the measured window: the engines poll on their own
                if probe is not None:   # the policies as they were in the window
                    probe.update(policies={"bus": threads(os.getpid()),
                                           "slave": threads(slave.pid),
                                           "master": threads(master.pid)})
                _stop(master)
            finally:
                _stop(slave)
    finally:
        for h in hog_procs:
            h.kill()
            h.wait()
    ta = turnarounds(cap, BAUD)
    if probe is not None:
        probe["records"] = [(r.t_us, r.port, len(r.data)) for r in read_capture(str(cap)).records]
    cap.unlink(missing_ok=True)
    if not ta:
        raise RuntimeError("no poll cycle on the bus capture")
    return {"n": len(ta), "p50": pct(ta, .5), "p99": pct(ta, .99), "max": max(ta)}


def _perf_start(path: Path, relay: int, slave: int) -> "Optional[subprocess.Popen[bytes]]":
    """``perf record`` of the events the attribution needs (bench/rt_trace.py)
    on CLOCK_MONOTONIC: every CPU's pty work items, the scheduler events of
    the relay and the slave engine only (a system-wide scheduler trace made
    perf itself a CPU hog and the round's tail worse). None without perf or
    the permission."""
    filters = {"sched:sched_wakeup": f"pid == {relay} || pid == {slave}",
               "sched:sched_switch": f"next_pid == {relay}"}
    args = ["perf", "record", "-q", "-a", "-k", "mono", "-o", str(path)]
    for ev in rt_trace.EVENTS:
        args += ["-e", ev] + (["--filter", filters[ev]] if ev in filters else [])
    try:
        p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None
    time.sleep(0.5)   # perf sets up its buffers before the window starts
    return p if p.poll() is None else None


def _rt_tid(ths: List[Dict[str, Any]], name: Optional[str] = None) -> Optional[int]:
    """The real-time thread of a process (by name when given)."""
    for t in ths:
        if t["policy"] in (1, 2) and (name is None or t["comm"] == name):
            return int(t["tid"])
    return None


def _policies(probe: Dict[str, Any]) -> Dict[str, List[str]]:
    """Per process, ``name:policy/prio`` of each thread (the policy check)."""
    pol = {0: "other", 1: "fifo", 2: "rr", 3: "batch", 5: "idle"}
    seen = probe.get("policies", {})
    return {k: [f"{t['comm']}:{pol.get(t['policy'], t['policy'])}/{t['rt_priority']}"
                for t in seen.get(k, [])] for k in ("bus", "slave", "master")}


def profile_round(seconds: float, tmp: Path) -> Optional[Dict[str, Any]]:
    """One hogs + real-time round under ``perf record``: each turnaround cut
    into the steps of its path (bench/rt_trace.py), and the policy of every
    thread of the three processes."""
    data = tmp / "rt-sched.perf"
    perfs: List["subprocess.Popen[bytes]"] = []

    def start(probe: Dict[str, Any]) -> None:
        relay, slave = _rt_tid(probe["bus"], "fap-vbus"), _rt_tid(probe["slave"])
        p = _perf_start(data, relay, slave) if relay and slave else None
        perfs.extend([p] if p else [])

    probe: Dict[str, Any] = {"on_ready": start}
    try:
        turn = one_round(True, 2, seconds, tmp, probe)
    finally:
        for p in perfs:
            p.send_signal(signal.SIGINT)
            p.wait(60)
    relay, slave = _rt_tid(probe.get("bus", []), "fap-vbus"), _rt_tid(probe.get("slave", []))
    if not perfs:
        return None if relay and slave else {
            "turnaround": turn, "threads": _policies(probe),
            "error": "no real-time relay or slave engine thread"}
    try:
        assert relay is not None and slave is not None
        script = subprocess.Popen(["perf", "script", "-i", str(data), "-F", rt_trace.FIELDS],
                                  stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        assert script.stdout is not None
        tr = rt_trace.parse(script.stdout, [relay, slave])
        script.wait()
    finally:
        data.unlink(missing_ok=True)
    tx = rt_trace.bursts(probe["records"], BAUD)
    lo, hi = probe["t0_window"]
    pairs = rt_trace.pairs(tx)
    off = rt_trace.align(tr, slave, relay, [b for _, b in pairs], lo, hi)
    rows = rt_trace.attribute(tr, relay, slave, pairs, off) if off is not None else []
    return {"turnaround": turn, "threads": _policies(probe),
            "steps": rt_trace.summary(rows, len(pairs)), "aligned": off is not None}


CONDITIONS = [("quiet", 0, False), ("quiet+rt", 0, True), ("hogs", 2, False),
              ("hogs+rt", 2, True)]
#: with ``idle_hogs``: the hogs at SCHED_IDLE (a waking kworker preempts them)
IDLE_CONDITION = ("idle-hogs+rt", 2, True)


def measure(rounds: int = 3, seconds: float = 5.0, profile: bool = True,
            idle_hogs: bool = False) -> Dict[str, Any]:
    """Every condition ``rounds`` times, interleaved (load drifts hit all
    four alike); per condition the medians of the rounds' p50/p99; with
    ``profile``, one more hogs + real-time round under perf (where each
    turnaround's time went, :func:`profile_round`); with ``idle_hogs`` a fifth condition, the hogs at
    SCHED_IDLE."""
    out: Dict[str, Any] = {"baud": BAUD, "rounds": rounds, "seconds": seconds,
                           "node_rt": NODE_RT, "bus_rt": BUS_RT,
                           "loadavg_before": os.getloadavg(), "runs": {}}
    with tempfile.TemporaryDirectory(prefix="bench-rt-") as d:
        conds = CONDITIONS + ([IDLE_CONDITION] if idle_hogs else [])
        for _ in range(rounds):
            for name, hogs, rt in conds:
                out["runs"].setdefault(name, []).append(one_round(
                    rt, hogs, seconds, Path(d), hog=IDLE_HOG if name == IDLE_CONDITION[0] else HOG))
        out["profile"] = profile_round(seconds, Path(d)) if profile else None
    out["loadavg_after"] = os.getloadavg()
    out["summary"] = {
        name: {k: statistics.median(r[k] for r in runs) for k in ("p50", "p99", "max", "n")}
        for name, runs in out["runs"].items()}
    return out


def profile_note(prof: Optional[Dict[str, Any]]) -> str:
    """The profile round in one clause: the step the tail (turnarounds at or
    above the round's p99) spends most in, with each step's share, and any
    thread of the path that did not get the asked policy."""
    if not prof:
        return ""
    st = prof.get("steps") or {}
    if not st.get("attributed"):
        return f"; profile: not attributed ({prof.get('error', 'trace not aligned')})"
    steps = st["steps"]
    top = st["top_step"]
    parts = ", ".join(f"{k} {v['tail_median']:.0f}" for k, v in steps.items())
    note = (f"; profile (one hogs+rt round, {st['attributed']}/{st['turnarounds']} turnarounds "
            f"traced, p99 {st['p99']:.0f} µs): the {st['tail_n']} tail turnarounds "
            f"(median {st['tail_turnaround_median']:.0f} µs) spend most in '{top}' (medians µs: "
            f"{parts}); the kernel's pty work (flush_to_ldisc, SCHED_OTHER kworker) waiting for "
            f"a CPU is {st['kworker_wait_share_of_tail'] * 100:.0f} % of a tail turnaround; "
            f"{top} p50/p99 {steps[top]['p50']:.0f}/{steps[top]['p99']:.0f} µs over all")
    th = prof.get("threads") or {}
    rt_ok = {k: any(":fifo/" in t for t in v) for k, v in th.items()}
    if th and not all(rt_ok.values()):
        note += "; NOT real-time: " + ", ".join(k for k, ok in rt_ok.items() if not ok)
    return note


def targets(res: Optional[Dict[str, Any]] = None, rounds: int = 3,
            seconds: float = 5.0, quick: bool = False) -> List["Target"]:
    """The issue-24 row: p99 turnaround with the option and two hogs <= 1 ms
    (FAP, 115200); the other conditions in the note. ``res`` from
    :func:`measure` (measured now when None; ``quick``: one round of 2 s,
    no perf round, a smoke test rather than a measurement)."""
    if res is None:
        res = measure(1, 2.0, False) if quick else measure(rounds, seconds)
    s = res["summary"]
    side = ", ".join(f"{n} p50/p99 {s[n]['p50']:.0f}/{s[n]['p99']:.0f} µs" for n, _, _ in CONDITIONS)
    la = res["loadavg_before"]
    note = (f"medians of {res['rounds']}x{res['seconds']:g} s; nodes {res['node_rt']}, bus "
            f"{res['bus_rt']}; {side}; load avg {la[0]:.2f} before, "
            f"{res['loadavg_after'][0]:.2f} after (2 cores)")
    note += profile_note(res.get("profile"))
    return [Target("rt-fap-p99-hogs-115200",
                   "FAP p99 turnaround <= 1 ms at 115200, real-time option, two CPU hogs",
                   s["hogs+rt"]["p99"], LIMIT_US, False, "µs", note)]


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--json", action="store_true", help="print the raw results as JSON")
    ap.add_argument("--no-profile", action="store_true",
                    help="skip the perf round (each turnaround cut into the steps of its path)")
    ap.add_argument("--idle-hogs", action="store_true",
                    help="also run the hogs at SCHED_IDLE, with the option")
    a = ap.parse_args(argv)
    res = measure(a.rounds, a.seconds, not a.no_profile, a.idle_hogs)
    if a.json:
        print(json.dumps(res, indent=1))
    print("| condition | p50 µs | p99 µs | max µs | turnarounds/round |")
    print("|---|---|---|---|---|")
    for name, r in res["summary"].items():
        print(f"| {name} | {r['p50']:.0f} | {r['p99']:.0f} | {r['max']:.0f} | {r['n']:.0f} |")
    from bench.targets import table
    print()
    print(table(targets(res)), end="")
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "_node":
        sys.exit(node_main(*sys.argv[2:5]))
    sys.exit(main())
