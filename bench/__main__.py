"""``python -m bench``: every benchmark of the project in one run, with plots.

Run from the repository root after ``meson setup build && meson compile -C
build`` and ``pip install '.[bench]'`` (fap_py and matplotlib). Every
exchange runs on a virtual bus (``fap_py.vbus``) opened here; the two sides
of an exchange are separate processes (``build/bench/wire/bench_wire`` for
the C engines and libmodbus, ``bench/g485/bench_g485.py`` for the Python
libraries), so each side's CPU is its own and the bus relay's is nobody's.

Measured (medians of ``--rounds`` runs, with min and max):

* paced efficiency at 9600, 115200 and 1,000,000 baud: exchanges/s as a
  share of the framing limit (10 bits per byte, request + reply bytes; a
  Modbus 3.5-character silence is not counted: the peers do not keep it on
  a pty), for every protocol and peer and the
  bare C and Python write/read floors, all on the same kind of bus;
* turnaround p50/p99/max from the bus capture (end of a request to the
  start of its answer, i.e. the responder's reaction time);
* unpaced exchanges/s and CPU µs per exchange, client and server;
* scale: 1/4/16 buses in one process and 1..31 slaves on one bus: CPU per
  poll cycle, idle CPU of the master, RSS per handle;
* Python overhead: fap_py against the C API (bench/fap_py).

Peers that are missing are named with how to get them, and skipped.
Results go to bench/results/<date>-<host>/ (results.json, table.md, *.png).

    python -m bench            # full run, under 10 minutes
    python -m bench --quick    # smoke test, under a minute (CI)
"""
from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import logging
import os
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

from bench import issue24, syscalls  # issue-24 target rows, perf probes
from bench.targets import Target, table

log = logging.getLogger("bench")
ROOT = Path(__file__).resolve().parent.parent
# The source tree's fap_py/ has no compiled _native: use the installed
# fap_py, never the checkout (also in the children: they run in a temp dir).
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT]
sys.path.insert(0, str(ROOT / "bench" / "g485"))
sys.path.insert(0, str(ROOT / "bench" / "fap_py"))


# kind -> (label, request bytes, reply bytes, silence chars per exchange, floor kind)
C_KINDS = {
    "bare": ("bare C write/read (floor)", 15, 15, 0, None),
    "fap-poll": ("FAP poll cycle", 15, 15, 0, "bare"),
    "fap-data": ("FAP DATA round trip", 38, 38, 0, "bare"),
    "exec": ("exec async", 16, 16, 0, "bare"),
    "mikroc": ("mikroC RS-485", 8, 8, 0, "bare"),
    "modbus": ("libmodbus RTU (10 regs)", 8, 25, 0, "bare"),
}
# bench_g485 runs: kind -> (label, req, rep, silence, floor, server argv tail, client factory name)
PY_KINDS = {
    "py-bare": ("bare Python write/read (floor)", 7, 16, 0, None, ["--serve", "canned"], "bare"),
    "g485": ("G485 (fap_py, check=none)", 7, 16, 0, "py-bare", None, "g485"),
    "minimalmodbus": ("minimalmodbus RTU", 8, 25, 0, "py-bare", ["--serve", "modbus"], "minimalmodbus"),
    "pymodbus": ("pymodbus sync RTU", 8, 25, 0, "py-bare", ["--serve", "modbus"], "pymodbus"),
    "dynamixel": ("Dynamixel SDK 1.0", 8, 16, 0, "py-bare", ["--serve", "dxl"], "dynamixel"),
}
PEER_HELP = {
    "modbus": "libmodbus: apt-get install libmodbus-dev, then meson setup --reconfigure build",
    "minimalmodbus": "pip install minimalmodbus",
    "pymodbus": "pip install pymodbus",
    "dynamixel": "pip install dynamixel-sdk",
}


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


BASE = "base:"   # a C kind run with the --baseline build's bench_wire


def spec(kind: str) -> Tuple[Any, ...]:
    base = kind.startswith(BASE)
    k = kind[len(BASE):] if base else kind
    t = C_KINDS.get(k) or PY_KINDS[k]
    return (t[0] + " [baseline build]",) + tuple(t[1:]) if base else t


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


def limit(kind: str, baud: int) -> float:
    spec_ = spec(kind)
    return baud / (10.0 * (spec_[1] + spec_[2] + spec_[3]))


def floor_rate(kind: str, baud: int, rows: Dict[str, Any]) -> Optional[float]:
    """Exchanges/s the bare floor would reach with this kind's frame sizes:
    the wire time of its bytes plus the floor's own measured per-exchange
    overhead (its exchange time minus its wire time)."""
    fl = floor_of(kind)
    if not fl or fl not in rows or "rate" not in rows[fl]:
        return None
    overhead = 1.0 / rows[fl]["rate"]["median"] - 1.0 / limit(fl, baud)
    return 1.0 / (1.0 / limit(kind, baud) + max(0.0, overhead))


def summary(values: List[float]) -> Dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


# -- turnaround from the bus capture ---------------------------------------------

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


def pct(values: List[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


# -- one exchange benchmark ------------------------------------------------------

def wrap(probe: Optional[syscalls.Probe], argv: List[str]) -> List[str]:
    return probe.wrap(argv) if probe else argv


def wrapped_pid(pid: int, probe: Optional[syscalls.Probe]) -> int:
    """The bench program's pid when perf runs it (perf's only child)."""
    if not probe or not probe.on:
        return pid
    kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    return int(kids[0]) if kids else pid


class Runner:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.exe = args.build_dir / "bench" / "wire" / "bench_wire"
        self.tmp = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench-{os.getpid()}"
        self.tmp.mkdir(parents=True, exist_ok=True)

    def c_run(self, kind: str, baud: int, seconds: float, ports: int = 2, buses: int = 1,
              slaves: int = 1, capture: bool = False, probe: str = "count") -> Dict[str, Any]:
        """One C client/server run; returns rates, CPU, syscalls per exchange
        (``probe``: "count" totals, "detail" per syscall name, "" none; needs
        perf) and (paced) turnarounds."""
        from fap_py.vbus import VirtualBus

        exe = self.exe
        if kind.startswith(BASE):
            exe, kind = self.args.baseline / "bench" / "wire" / "bench_wire", kind[len(BASE):]
        cap = self.tmp / f"{kind}-{baud}.cap" if capture and baud else None
        pace = ["--baud", str(baud or 115200)] + ([] if baud else ["--unpaced"])
        with_buses = []
        try:
            for b in range(buses):
                with_buses.append(VirtualBus(ports=ports, baud=baud or None, seed=1,
                                             capture=str(cap) if cap and b == 0 else None))
            client_paths = ",".join(bus.paths[0] for bus in with_buses)
            server_paths = ",".join(p for bus in with_buses for p in bus.paths[1:])
            kinds = {"server": syscalls.Probe(detail=probe == "detail"),
                     "client": syscalls.Probe(detail=probe == "detail")} if probe else {}
            sp, cp = kinds.get("server"), kinds.get("client")
            srv = subprocess.Popen(wrap(sp, [str(exe), "serve", kind, server_paths] + pace
                                        + (["--same-id"] if buses > 1 else [])),
                                   stdout=subprocess.PIPE, text=True,
                                   pass_fds=sp.pass_fds if sp else ())
            srv_pid = srv.pid
            if sp:
                sp.started()
            try:
                if srv.stdout is None or srv.stdout.readline().strip() != "ready":
                    raise RuntimeError(f"bench_wire serve {kind} did not start")
                srv_pid = wrapped_pid(srv.pid, sp)
                cli = subprocess.Popen(wrap(cp, [str(exe), "client", kind, client_paths,
                                                 "--seconds", str(seconds), "--slaves",
                                                 str(slaves)] + pace),
                                       stdout=subprocess.PIPE, text=True,
                                       pass_fds=cp.pass_fds if cp else ())
                if cp:
                    cp.started()
                assert cli.stdout is not None
                if cli.stdout.readline().strip() != "measuring":
                    raise RuntimeError(f"bench_wire client {kind} failed")
                for pr in kinds.values():
                    pr.enable()
                s0, w0 = proc_cpu(srv_pid), proc_wakeups(srv_pid)
                res = json.loads(cli.stdout.readline())
                s1, w1 = proc_cpu(srv_pid), proc_wakeups(srv_pid)
                if sp:
                    sp.disable()
                if cp:
                    cp.ended()                  # the client exits: perf stops there
                cli.wait(10)
            finally:
                os.kill(srv_pid, signal.SIGTERM)
                srv.wait(60)                    # perf closes its counters
            seen = {side: pr.result() for side, pr in kinds.items()}
        finally:
            for bus in with_buses:
                bus.close()
        n = max(1, res["exchanges"])
        out = {"rate": res["exchanges"] / res["seconds"], "client_us": res["cpu_s"] / n * 1e6,
               "server_us": (s1 - s0) / n * 1e6, "client_load": res["cpu_s"] / res["seconds"],
               "failed": res["failed"], "rss_kib_per_handle": res["rss_kib_per_handle"],
               "client_wakeups": res["wakeups"] / n, "server_wakeups": (w1 - w0) / n}
        rate = max(out["rate"], 1e-9)
        for side, per_s in seen.items():        # perf's window, per exchange
            if per_s:
                out[f"{side}_syscalls"] = per_s["syscalls"] / rate
                if probe == "detail":
                    out[f"{side}_by_syscall"] = {k: v / rate for k, v in per_s.items()}
        if cap:
            out["turnaround_us"] = turnarounds(cap, baud)
            cap.unlink(missing_ok=True)
        return out

    def py_run(self, kind: str, baud: int, seconds: float, capture: bool = False) -> Dict[str, Any]:
        """One bench_g485 client (this process) / server (child) run."""
        import bench_g485 as g

        from fap_py.vbus import VirtualBus

        label, _, _, _, _, serve_tail, client = PY_KINDS[kind]
        b = baud or 115200
        if serve_tail is None:
            server_argv = [sys.executable, "-m", "fap_py", "g485", "sim", "--address", "1",
                           "--baud", str(b), "--port"]
        else:
            server_argv = [sys.executable, str(ROOT / "bench" / "g485" / "bench_g485.py"),
                           "--baud", str(b)] + serve_tail
        factory = {
            "bare": lambda p: g.bare_client(p, spin=False),
            "g485": lambda p: g.g485_client(p, b, "none"),
            "minimalmodbus": lambda p: g.minimalmodbus_client(p, b),
            "pymodbus": lambda p: g.pymodbus_sync_client(p, b),
            "dynamixel": lambda p: g.dynamixel_client(p, b),
        }[client]
        cap = self.tmp / f"{kind}-{baud}.cap" if capture and baud else None
        with VirtualBus(ports=2, baud=baud or None, seed=1, capture=str(cap) if cap else None) as bus:
            res = g.run_pair(server_argv + [bus.paths[1]], lambda: factory(bus.paths[0]), seconds)
        out = {"rate": res["rate"], "client_us": res["client_us"], "server_us": res["server_us"],
               "client_load": res["client_load"], "failed": res["errors"]}
        if cap:
            out["turnaround_us"] = turnarounds(cap, baud)
            cap.unlink(missing_ok=True)
        return out


# -- the plan ----------------------------------------------------------------------

def available(args: argparse.Namespace, runner: Runner) -> Tuple[List[str], Dict[str, str]]:
    """Kinds that can run here, and the missing ones with how to get them."""
    kinds = list(C_KINDS) + list(PY_KINDS)
    missing: Dict[str, str] = {}
    probe = subprocess.run([str(runner.exe), "serve", "modbus", "/nonexistent"],
                           capture_output=True, text=True)
    if probe.returncode == 2:
        missing["modbus"] = PEER_HELP["modbus"]
    for kind, mod in (("minimalmodbus", "minimalmodbus"), ("pymodbus", "pymodbus"),
                      ("dynamixel", "dynamixel_sdk")):
        if importlib.util.find_spec(mod) is None:
            missing[kind] = PEER_HELP[kind]
    return [k for k in kinds if k not in missing], missing


def measure_series(runner: Runner, kind: str, baud: int, rounds: int, seconds: float) -> Dict[str, Any]:
    runs = []
    for r in range(rounds):
        cap = r == 0 and baud != 0
        try:
            if kind in C_KINDS or kind.startswith(BASE):
                runs.append(runner.c_run(kind, baud, seconds, capture=cap))
            else:
                runs.append(runner.py_run(kind, baud, seconds, capture=cap))
        except Exception as e:       # one failed run is reported, the rest goes on
            log.warning("%s at %s baud: run failed: %s", kind, baud or "unpaced", e)
    if not runs:
        return {"error": "all runs failed"}
    out: Dict[str, Any] = {k: summary([r[k] for r in runs])
                           for k in ("rate", "client_us", "server_us", "client_load",
                                     "client_wakeups", "server_wakeups", "client_syscalls",
                                     "server_syscalls") if k in runs[0]}
    out["failed"] = sum(r["failed"] for r in runs)
    if baud:
        out["limit"] = limit(kind, baud)
        out["efficiency"] = summary([r["rate"] / out["limit"] for r in runs])
    ta = [t for r in runs for t in r.get("turnaround_us", [])]
    if ta:
        out["turnaround_us"] = {"p50": pct(ta, .5), "p99": pct(ta, .99), "max": max(ta), "n": len(ta)}
        step = max(1, len(ta) // 500)      # a small file: every k-th, whole µs
        out["turnaround_sample"] = [round(t) for t in ta[::step]]
    return out


def scale_series(runner: Runner, baud: int, rounds: int, seconds: float, quick: bool) -> Dict[str, Any]:
    res: Dict[str, Any] = {"buses": {}, "slaves": {}}
    for buses in ([1, 4] if quick else [1, 4, 16]):
        runs = [runner.c_run("fap-poll", baud, seconds, buses=buses) for _ in range(rounds)]
        res["buses"][buses] = {"cpu_us_per_cycle": summary([r["client_us"] for r in runs]),
                               "cycles_per_s": summary([r["rate"] for r in runs]),
                               "master_load": summary([r["client_load"] for r in runs]),
                               "rss_kib_per_handle": summary([r["rss_kib_per_handle"] for r in runs])}
    for slaves in ([1, 31] if quick else [1, 4, 16, 31]):
        runs = [runner.c_run("fap-poll", baud, seconds, ports=slaves + 1, slaves=slaves)
                for _ in range(rounds)]
        res["slaves"][slaves] = {"cpu_us_per_cycle": summary([r["client_us"] for r in runs]),
                                 "cycles_per_s": summary([r["rate"] for r in runs]),
                                 "master_load": summary([r["client_load"] for r in runs])}
    return res


PROFILE_KINDS = ("bare", "fap-poll", "fap-data", "exec", "mikroc", "modbus")


def profile(runner: Runner, kinds: List[str], bauds: List[int], rounds: int,
            seconds: float) -> Dict[str, Any]:
    """Per exchange, each side: CPU µs, wake-ups and every syscall by name
    (perf stat's per-syscall tracepoints), median of ``rounds`` runs."""
    out: Dict[str, Any] = {}
    for baud in bauds:
        for kind in [k for k in PROFILE_KINDS if k in kinds]:
            runs = [runner.c_run(kind, baud, seconds, probe="detail") for _ in range(rounds)]
            row: Dict[str, Any] = {k: statistics.median(r[k] for r in runs)
                                   for k in ("rate", "client_us", "server_us",
                                             "client_wakeups", "server_wakeups")}
            for side in ("client", "server"):
                names = {n for r in runs for n in r.get(f"{side}_by_syscall", {})}
                row[side] = {n: statistics.median(r.get(f"{side}_by_syscall", {}).get(n, 0.0)
                                                  for r in runs) for n in sorted(names)}
            out[f"{kind}@{baud}"] = row
    return out


def profile_markdown(prof: Dict[str, Any]) -> str:
    L = ["| exchange | side | CPU µs | wake-ups | syscalls | by syscall (per exchange) |",
         "|---|---|---|---|---|---|"]
    for key, row in prof.items():
        kind, baud = key.split("@")
        for side in ("client", "server"):
            by = row[side]
            total = by.get("syscalls", 0.0)
            names = sorted(((v, n) for n, v in by.items() if n != "syscalls" and v >= 0.05),
                           reverse=True)
            L.append(f"| {label(kind)} @ {baud} | {side} | {row[side + '_us']:.0f} | "
                     f"{row[side + '_wakeups']:.1f} | {total:.1f} | "
                     + ", ".join(f"{n} {v:.2g}" for v, n in names) + " |")
    return "\n".join(L) + "\n"


def python_overhead(args: argparse.Namespace, quick: bool) -> Dict[str, Any]:
    """fap_py against the C API on one unpaced bus (bench/fap_py).

    Round trips (issue 24's target) are interleaved C / fap_py / asyncio runs,
    the median of the per-pair ratios (``bench_fap_py.paired``, the same
    measurement as ``bench_fap_py.py --paired``); each row also carries the
    master's poll turns per round trip and the load average. ``calls`` (the
    binding's cost per call, no wire) is the median of 3 interleaved pairs.
    """
    import statistics

    import bench_fap_py as fp

    exe = args.build_dir / "bench" / "fap_py" / "bench_fapx_c"
    bus = fp.BusProcess(2, 0)
    out: Dict[str, Any] = {}
    try:
        n = 200 if quick else fp.PAIR_COUNT
        pr = fp.paired(exe, bus.paths, pairs=7 if quick else fp.PAIRS, count=n, size=16)
        common = {"pairs": pr["pairs"], "dropped": len(pr["dropped"]), "count": n,
                  "load_before": pr["load_before"],
                  "load_after": pr["load_after"], "c_polls": pr["polls"]["c"]}
        out["round-trip"] = dict(
            common, c_rate=pr["rate"]["c"], py_rate=pr["rate"]["py"], c_cpu_us=pr["cpu_us"]["c"],
            py_cpu_us=pr["cpu_us"]["py"], py_polls=pr["polls"]["py"], ratio=pr["ratio"],
            ratio_min=pr["ratio_min"], ratio_max=pr["ratio_max"],
            ratios=[p["py"]["rate"] / p["c"]["rate"] for p in pr["per_pair"]])
        calls = [(fp.run_c(exe, bus.paths, "calls", 10000, 16),
                  fp.run_py(bus.paths, "calls", 10000, 16)) for _ in range(3)]
        out["calls"] = {"c_rate": statistics.median(c.rate for c, _ in calls),
                        "py_rate": statistics.median(p.rate for _, p in calls),
                        "c_cpu_us": statistics.median(c.cpu_s / c.count * 1e6 for c, _ in calls),
                        "py_cpu_us": statistics.median(p.cpu_s / p.count * 1e6 for _, p in calls)}
        out["round-trip asyncio"] = dict(
            common, py_rate=pr["rate"]["aio"], py_cpu_us=pr["cpu_us"]["aio"],
            py_polls=pr["polls"]["aio"], ratio=pr["aio_ratio"])
    finally:
        bus.close()
    return out


def codec_throughput(runner: Runner) -> Dict[str, Any]:
    """Payload MB/s through the encoders and decoders, C (bench_wire codec)
    and Python (fap_py: exec async and mikroC through cffi, G485 pure)."""
    out: Dict[str, Any] = {"c": json.loads(subprocess.run(
        [str(runner.exe), "codec"], capture_output=True, text=True, check=True).stdout)}
    from fap_py import execasync, mikroc
    from fap_py.g485 import codec as g

    def timed(fn: Any, payload: int) -> float:
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < 0.3:
            for _ in range(20):
                fn()
            n += 20
        return n * payload / (time.perf_counter() - t0) / 1e6

    data = bytes(range(255))
    ef = execasync.encode(1, data)
    mf = mikroc.encode(1, b"abc")
    gdata = bytes(range(32))
    gf = g.encode_write(1, 1, gdata)
    out["python"] = {
        "exec_encode": timed(lambda: execasync.encode(1, data), 255),
        "exec_decode": timed(lambda: execasync.Decoder().feed(ef), 255),
        "mikroc_encode": timed(lambda: mikroc.encode(1, b"abc"), 3),
        "mikroc_decode": timed(lambda: mikroc.Decoder().feed(mf), 3),
        "g485_encode": timed(lambda: g.encode_write(1, 1, gdata), len(gdata)),
        "g485_decode": timed(lambda: g.Parser().feed(gf), len(gdata)),
    }
    return out


# -- output ------------------------------------------------------------------------

def label(kind: str) -> str:
    return spec(kind)[0]


def floor_of(kind: str) -> Optional[str]:
    return spec(kind)[4]


def fmt(s: Dict[str, float], f: str = "{:.0f}") -> str:
    return f"{f.format(s['median'])} ({f.format(s['min'])}–{f.format(s['max'])})"


def targets(res: Dict[str, Any]) -> List[str]:
    """Issue 16's targets, each checked against this run (a report, not an assertion)."""
    L = ["## Earlier targets (issue 16) in this run", ""]

    def line(ok: Optional[bool], text: str) -> None:
        L.append(f"- {'met' if ok else 'MISSED' if ok is not None else 'n/a'}: {text}")

    for baud in ("115200", "1000000"):
        rows = res["paced"].get(baud, {})
        for kind in ("fap-poll", "exec", "mikroc"):   # G485: the paired rows below (bench/g485/paired.py)
            r = rows.get(kind)
            fr = floor_rate(kind, int(baud), rows) if r and "rate" in r else None
            if fr:
                share = 100 * r["rate"]["median"] / fr
                line(share >= 97, f"{label(kind)} at {baud}: {share:.1f} % of the floor's efficiency (target 97 %)")
        mb = rows.get("modbus")
        for kind in ("fap-poll", "exec", "mikroc"):
            r = rows.get(kind)
            if r and mb and "client_us" in r and "client_us" in mb:
                c, m = r["client_us"]["median"], mb["client_us"]["median"]
                line(c <= m / 2, f"{label(kind)} at {baud}: client CPU {c:.0f} µs/exchange vs libmodbus {m:.0f} (target ≤ half)")
            b = rows.get(BASE + kind)
            if r and b and r.get("turnaround_us") and b.get("turnaround_us"):
                n, o = r["turnaround_us"]["p50"], b["turnaround_us"]["p50"]
                line(n <= o * 1.1, f"{label(kind)} at {baud}: turnaround p50 {n:.0f} µs vs {o:.0f} µs before (target no worse)")
    sc = res["scale"].get("115200")
    if sc:
        one = {str(k): v for k, v in sc["buses"].items()}["1"]
        load = 100 * one["master_load"]["median"]
        line(load < 2, f"idle FAP master at 115200: {load:.2f} % of a core (target < 2 %)")
    for baud, sc in res["scale"].items():
        b = {str(k): v for k, v in sc["buses"].items()}
        if "1" in b and "16" in b:
            a, z = b["1"]["cpu_us_per_cycle"]["median"], b["16"]["cpu_us_per_cycle"]["median"]
            line(z <= 1.2 * a, f"CPU per poll cycle at {baud}, 1 → 16 buses: {a:.1f} → {z:.1f} µs "
                               "(target flat: at most 20 % above 1 bus)")
        most = max(b, key=int)            # many handles: the process's own first-use pages shared out
        rss = b[most]["rss_kib_per_handle"]["median"]
        line(rss < 256, f"RSS per FAP handle at {baud}: {rss:.0f} KiB with {most} handles in one process "
                        f"({b['1']['rss_kib_per_handle']['median']:.0f} KiB for the first) (target < 256 KiB)")
    L.append("")
    if res.get("g485_targets"):   # G485 vs the bare Python floor: paired rounds (bench/g485/paired.py)
        from bench.targets import Target, table
        L += ["## G485 targets (issue 24): paired rounds, paced", "",
              table([Target(**{k: v for k, v in t.items() if k != "met"}) for t in res["g485_targets"]]), ""]
    return L


def markdown(res: Dict[str, Any]) -> str:
    L = [f"# Benchmark {res['date']} on {res['host']}", "",
         f"{res['machine']}; load average before/after: {res['loadavg_before']} / "
         f"{res['loadavg_after']}; rounds {res['rounds']}, {res['seconds']} s each; "
         "median (min–max).", "",
         "Efficiency: exchanges/s as a share of the framing limit (10 bits per byte, request + "
         "reply bytes; Modbus's 3.5-character silence not counted, the peers do not keep it on a pty). vs floor: exchanges/s against what the bare "
         "write/read floor (C for the C engines, Python for the Python libraries) reaches with the "
         "same frame sizes (their wire time plus the floor's measured per-exchange overhead). "
         "Wake-ups/x: voluntary context switches per exchange (C sides only; does not "
         "depend on the machine's load as CPU time does). "
         "Turnaround: end of a request to the start of its answer, from the bus capture.", ""]
    if res["missing"]:
        L += ["Missing peers (skipped): " + "; ".join(f"{k}: {v}" for k, v in res["missing"].items()), ""]
    for baud in res["bauds"]:
        rows = res["paced"][str(baud)]
        L += [f"## Paced at {baud} baud", "",
              "| protocol / peer | exchanges/s | framing limit/s | efficiency | vs floor | "
              "client µs/x | server µs/x | wake-ups/x client, server | syscalls/x client, server | "
              "turnaround p50 / p99 / max µs |",
              "|---|---|---|---|---|---|---|---|---|---|"]
        for kind, r in rows.items():
            if "error" in r:
                L.append(f"| {label(kind)} | failed | | | | | | | | |")
                continue
            fr = floor_rate(kind, baud, rows)
            vs = f"{100 * r['rate']['median'] / fr:.1f} %" if fr else ""
            ta = r.get("turnaround_us")
            tas = f"{ta['p50']:.0f} / {ta['p99']:.0f} / {ta['max']:.0f}" if ta else ""
            wk = (f"{r['client_wakeups']['median']:.1f}, {r['server_wakeups']['median']:.1f}"
                  if "client_wakeups" in r else "")
            sc = (f"{r['client_syscalls']['median']:.1f}, {r['server_syscalls']['median']:.1f}"
                  if "client_syscalls" in r and "server_syscalls" in r else "")
            L.append(f"| {label(kind)} | {fmt(r['rate'])} | {r['limit']:.0f} | "
                     f"{fmt({k: 100 * v for k, v in r['efficiency'].items()}, '{:.1f}')} % | {vs} | "
                     f"{fmt(r['client_us'])} | {fmt(r['server_us'])} | {wk} | {sc} | {tas} |")
        L.append("")
    L += ["## Unpaced (as fast as the ptys go)", "",
          "| protocol / peer | exchanges/s | client µs/x | server µs/x |", "|---|---|---|---|"]
    for kind, r in res["unpaced"].items():
        if "error" not in r:
            L.append(f"| {label(kind)} | {fmt(r['rate'])} | {fmt(r['client_us'])} | {fmt(r['server_us'])} |")
    L.append("")
    for baud, sc in res["scale"].items():
        L += [f"## Scale: FAP master, paced at {baud} baud (slaves with nothing to send)", "",
              "| buses in one process | poll cycles/s | master CPU µs/cycle | master load | RSS KiB/handle |",
              "|---|---|---|---|---|"]
        for n, r in sc["buses"].items():
            L.append(f"| {n} | {fmt(r['cycles_per_s'])} | {fmt(r['cpu_us_per_cycle'], '{:.1f}')} | "
                     f"{fmt({k: 100 * v for k, v in r['master_load'].items()}, '{:.2f}')} % | "
                     f"{fmt(r['rss_kib_per_handle'])} |")
        L += ["", "| slaves on one bus | poll cycles/s | master CPU µs/cycle | master load |", "|---|---|---|---|"]
        for n, r in sc["slaves"].items():
            L.append(f"| {n} | {fmt(r['cycles_per_s'])} | {fmt(r['cpu_us_per_cycle'], '{:.1f}')} | "
                     f"{fmt({k: 100 * v for k, v in r['master_load'].items()}, '{:.2f}')} % |")
        L.append("")
    if res.get("python"):
        L += ["## Python overhead (fap_py vs C API, unpaced, 16-byte messages)", "",
              "| mode | C msgs/s | Python msgs/s | C CPU µs/msg | Python CPU µs/msg |", "|---|---|---|---|---|"]
        for mode, r in res["python"].items():
            L.append(f"| {mode} | {r.get('c_rate', float('nan')):.0f} | {r['py_rate']:.0f} | "
                     f"{r.get('c_cpu_us', float('nan')):.1f} | {r['py_cpu_us']:.1f} |")
        L.append("")
    L += ["## Targets of issue 24 in this run", "",
          "Medians of the run's rounds; CPU ratios: this engine's CPU µs per exchange over "
          "libmodbus's read, the same side, the same run. Load average before/after: "
          f"{res['loadavg_before']} / {res.get('loadavg_after', '?')}.", "",
          table([Target(**{k: v for k, v in t.items() if k != "met"})
                 for t in res.get("targets", [])])]
    L += targets(res)
    if res.get("codec"):
        c, p = res["codec"]["c"], res["codec"]["python"]
        L += ["## Codec throughput (payload MB/s, no I/O)", "",
              "| codec | C encode | C decode | Python encode | Python decode |", "|---|---|---|---|---|"]
        for name, cname in (("FAP (1024-byte DATA)", "fap"), ("exec async (255 bytes)", "exec"),
                            ("mikroC (3 bytes)", "mikroc"), ("G485 (32-byte write)", "g485")):
            def g(d: Dict[str, float], k: str) -> str:
                return f"{d[k]:.2f}" if k in d else "—"
            L.append(f"| {name} | {g(c, cname + '_encode')} | {g(c, cname + '_decode')} | "
                     f"{g(p, cname + '_encode')} | {g(p, cname + '_decode')} |")
        L += ["", "FAP has no Python codec (fap_py drives the C engine); G485 is pure Python.", ""]
    from bench import net
    L += net.markdown_lines(res)   # ser2net rows and the mismatched-baud case
    return "\n".join(L)


def have_matplotlib() -> bool:
    """Plots need matplotlib (``pip install '.[bench]'``); the measurements do not."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def plots(res: Dict[str, Any], out: Path) -> List[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made = []
    bauds = res["bauds"]
    kinds = list(res["paced"][str(bauds[0])])
    # 1. efficiency vs baud
    fig, ax = plt.subplots(figsize=(9, 5.5))
    colors = iter(plt.get_cmap("tab20").colors[::2] + plt.get_cmap("tab20").colors[1::2])
    for kind in kinds:
        pts = [(b, res["paced"][str(b)][kind]["efficiency"]) for b in bauds
               if "efficiency" in res["paced"][str(b)].get(kind, {})]
        if not pts:
            continue
        floor = floor_of(kind) is None
        python = kind in PY_KINDS
        xs = [b * (1.03 if python else 1) for b, _ in pts]   # side by side, not on top
        ys = [100 * e["median"] for _, e in pts]
        err = [[100 * (e["median"] - e["min"]) for _, e in pts], [100 * (e["max"] - e["median"]) for _, e in pts]]
        ax.errorbar(xs, ys, yerr=err, fmt="--" if floor else "-", marker="s" if python else "o",
                    color="black" if floor and not python else "grey" if floor else next(colors),
                    capsize=3, label=label(kind) + (" (Python)" if python and not floor else ""))
    ax.set_xscale("log")
    ax.set_xticks(bauds, [f"{b:,}" for b in bauds])
    ax.set_ylim(0, 105)
    ax.set_xlabel("baud (paced virtual bus)")
    ax.set_ylabel("exchanges/s as % of the framing limit")
    ax.set_title(f"Efficiency vs baud rate ({res['host']}, {res['date']}; median, bars min–max)")
    ax.grid(True, which="both", alpha=.3)
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "efficiency.png", dpi=90)
    plt.close(fig)
    made.append("efficiency.png")
    # 2. turnaround distributions at 115200 (or the middle baud)
    b = str(115200 if 115200 in bauds else bauds[0])
    data = [(label(k), res["paced"][b][k]["turnaround_sample"]) for k in kinds
            if res["paced"][b].get(k, {}).get("turnaround_sample")]
    if data:
        fig, ax = plt.subplots(figsize=(9, 5.5))
        ax.boxplot([d for _, d in data], orientation="horizontal", whis=(1, 99), showfliers=False)
        ax.set_yticks(range(1, len(data) + 1), [n for n, _ in data], fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("responder turnaround µs (end of request to start of answer; whiskers p1–p99)")
        ax.set_title(f"Turnaround from the bus capture, paced at {b} baud")
        ax.grid(True, axis="x", which="both", alpha=.3)
        fig.tight_layout()
        fig.savefig(out / "turnaround.png", dpi=90)
        plt.close(fig)
        made.append("turnaround.png")
    # 3. CPU per exchange (client and server) at each baud and unpaced
    cols = [str(x) for x in bauds] + ["unpaced"]
    fig, axes = plt.subplots(1, len(cols), figsize=(4 * len(cols), 5.5), sharey=True)
    for ax, col in zip(axes, cols):
        rows = res["unpaced"] if col == "unpaced" else res["paced"][col]
        ks = [k for k in kinds if k in rows and "client_us" in rows[k]]
        y = range(len(ks))
        ax.barh([i - .2 for i in y], [rows[k]["client_us"]["median"] for k in ks], .4, label="client")
        ax.barh([i + .2 for i in y], [rows[k]["server_us"]["median"] for k in ks], .4, label="server")
        for i, k in zip(y, ks):           # the numbers: busy-waiting peers span 3 decades
            ax.text(rows[k]["client_us"]["median"] * 1.1, i - .2, f"{rows[k]['client_us']['median']:.0f}",
                    va="center", fontsize=7)
        ax.set_yticks(list(y), [label(k) for k in ks], fontsize=8)
        ax.set_xscale("log")
        ax.set_xlim(1, 30000)                 # every bar starts at 1 µs: lengths compare
        ax.set_title(f"{col}{' baud' if col != 'unpaced' else ''}")
        ax.set_xlabel("CPU µs per exchange (log)")
        ax.grid(True, axis="x", which="both", alpha=.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("CPU per exchange (lower is better)")
    fig.tight_layout()
    fig.savefig(out / "cpu.png", dpi=90)
    plt.close(fig)
    made.append("cpu.png")
    # 4. scaling
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for baud, sc in res["scale"].items():
        xs = sorted(int(n) for n in sc["buses"])
        a1.plot(xs, [sc["buses"][n]["cpu_us_per_cycle"]["median"] for n in sc["buses"]], marker="o",
                label=f"{baud} baud")
        xs2 = [int(n) for n in sc["slaves"]]
        a2.plot(xs2, [100 * sc["slaves"][n]["master_load"]["median"] for n in sc["slaves"]], marker="o",
                label=f"{baud} baud")
    a1.set_xscale("log", base=2)
    xs_all = sorted({int(n) for sc in res["scale"].values() for n in sc["buses"]})
    a1.set_xticks(xs_all, [str(x) for x in xs_all])
    a1.set_xlabel("buses (one FAP master each) in one process")
    a1.set_ylabel("master CPU µs per poll cycle")
    a1.set_ylim(bottom=0)
    a2.set_xlabel("slaves on one bus (nothing to send)")
    a2.set_ylabel("idle master CPU, % of a core")
    a2.set_ylim(bottom=0)
    for a in (a1, a2):
        a.grid(True, alpha=.3)
        a.legend(fontsize=8)
    fig.suptitle("FAP master scaling on a paced bus")
    fig.tight_layout()
    fig.savefig(out / "scaling.png", dpi=90)
    plt.close(fig)
    made.append("scaling.png")
    return made


def loadavg() -> str:
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m bench",
        description="Run every benchmark on the virtual bus; write JSON, a Markdown table and PNG plots.",
        epilog="example: python -m bench --quick --out /tmp/bench-smoke",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke test: 115200 only, short runs, no Python peers (< 1 min)")
    ap.add_argument("--build-dir", type=Path, default=ROOT / "build", help="meson build directory (default: build/ in the repository)")
    ap.add_argument("--rounds", type=int, help="runs per cell (default 3, quick 1)")
    ap.add_argument("--seconds", type=float, help="measuring time per run (default 1.5, quick 0.3)")
    ap.add_argument("--out", type=Path, help="result directory (default bench/results/<date>-<host>)")
    ap.add_argument("--only", help="comma list of kinds to run (default: all available): "
                    + ",".join(list(C_KINDS) + list(PY_KINDS)))
    ap.add_argument("--baseline", type=Path, metavar="BUILD_DIR",
                    help="also run the FAP, exec async and mikroC kinds with the bench_wire of "
                         "another build (e.g. of the previous commit), same bus, same run")
    ap.add_argument("--skip-parts", action="store_true",
                    help="leave out the other benches' issue-24 rows (G485, bridge, real-time): "
                         "shown as not measured")
    ap.add_argument("--readme", type=Path, metavar="RESULT_DIR", nargs="?", const=Path("latest"),
                    help="measure nothing: regenerate README.md's benchmark section from a run's "
                         "results.json (default: the newest bench/results/*)")
    ap.add_argument("--profile", action="store_true",
                    help="only the profile: per exchange and side, CPU, wake-ups and every "
                         "syscall by name (perf), C kinds at 115200 and 1 Mbaud")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="progress on stderr")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="bench: %(message)s")
    if args.readme:
        from bench import readme
        return readme.main(args.readme, ROOT)
    quick = args.quick
    rounds = args.rounds or (1 if quick else 3)
    seconds = args.seconds or (0.3 if quick else 1.5)
    host = socket.gethostname()
    date = datetime.date.today().isoformat()
    out = args.out or ROOT / "bench" / "results" / f"{date}-{host}"
    args.build_dir = args.build_dir.resolve()
    out = out.resolve()
    runner = Runner(args)
    os.chdir(runner.tmp)
    if not runner.exe.exists():
        print(f"bench: error: {runner.exe} missing: run meson setup build && meson compile -C build",
              file=sys.stderr)
        return 3
    kinds, missing = available(args, runner)
    if args.only:
        unknown = set(args.only.split(",")) - set(C_KINDS) - set(PY_KINDS)
        if unknown:
            ap.error(f"unknown kind(s) in --only: {', '.join(sorted(unknown))}")
        kinds = [k for k in kinds if k in args.only.split(",")]
    for k, how in missing.items():
        print(f"bench: peer {k} missing, skipped ({how})", file=sys.stderr)
    plotting = have_matplotlib()
    if not plotting:       # said before the measuring starts, as for a missing peer
        print("bench: matplotlib missing, plots skipped (pip install '.[bench]')", file=sys.stderr)
    if quick:
        kinds = [k for k in kinds if k in ("bare", "fap-poll", "fap-data", "exec", "mikroc", "modbus",
                                           "py-bare", "g485")]
    if args.baseline:
        args.baseline = args.baseline.resolve()
        at = kinds.index("mikroc") + 1 if "mikroc" in kinds else len(kinds)
        kinds[at:at] = [BASE + k for k in ("fap-poll", "fap-data", "exec", "mikroc") if k in kinds]
    if args.profile:
        if not syscalls.have_perf():
            print("bench: --profile needs perf (apt-get install linux-perf)", file=sys.stderr)
            return 3
        prof = profile(runner, kinds, [115200, 1000000], rounds, seconds)
        out.mkdir(parents=True, exist_ok=True)
        (out / "profile.json").write_text(json.dumps({"loadavg": loadavg(), "profile": prof},
                                                     indent=1))
        print(f"load average {loadavg()}\n\n" + profile_markdown(prof))
        return 0
    bauds = [115200] if quick else [9600, 115200, 1000000]
    scale_bauds = [115200] if quick else [115200, 1000000]
    t_start = time.monotonic()
    res: Dict[str, Any] = {
        "date": date, "host": host, "loadavg_before": loadavg(), "rounds": rounds, "seconds": seconds,
        "machine": f"{os.cpu_count()} CPUs, {os.uname().sysname} {os.uname().release} {os.uname().machine}",
        "bauds": bauds, "missing": missing, "paced": {}, "unpaced": {}, "scale": {}}
    # one step per measured cell; a rich bar on a terminal (stderr), nothing otherwise
    from fap_py.commands._node import Progress  # the installed fap_py (sys.path above)

    steps = len(bauds) * len(kinds) + len(kinds) + len(scale_bauds) + 5
    with Progress(steps, "bench", enabled=True) as bar:
        for baud in bauds:
            res["paced"][str(baud)] = {}
            for kind in kinds:
                log.info("paced %d: %s", baud, kind)
                bar.advance(f"paced {baud}: {kind}")
                res["paced"][str(baud)][kind] = measure_series(runner, kind, baud, rounds,
                                                               seconds if baud > 9600 else seconds * 2)
        for kind in kinds:
            log.info("unpaced: %s", kind)
            bar.advance(f"unpaced: {kind}")
            res["unpaced"][kind] = measure_series(runner, kind, 0, rounds, seconds)
        for baud in scale_bauds:
            log.info("scale at %d", baud)
            bar.advance(f"scale at {baud}")
            res["scale"][str(baud)] = scale_series(runner, baud, 1 if quick else 2, seconds, quick)
        from bench import net  # network transports and mismatched baud (bench/net.py)
        bar.advance("network transports")
        if net.have_ser2net():
            log.info("through ser2net")
            res["network"] = {"baud": 115200,
                              "rows": net.network_series(runner, 115200, rounds, seconds, quick)}
        else:
            print("bench: ser2net missing, network rows skipped (apt-get install ser2net)",
                  file=sys.stderr)
        log.info("mismatched baud")
        bar.advance("mismatched baud")
        res["mismatch"] = net.mismatch_series(runner, rounds, seconds, quick)
        bar.advance("Python overhead")
        try:
            res["python"] = python_overhead(args, quick)
        except Exception as e:
            log.warning("python overhead: %s", e)
        if "g485" in kinds:
            bar.advance("G485 paired")
            try:
                import paired as g485_paired  # bench/g485/paired.py
                res["g485_paired"] = {}
                res["g485_targets"] = [t.as_dict() for t in g485_paired.targets(
                    [b for b in bauds if b >= 115200], results=res["g485_paired"])]
            except Exception as e:
                log.warning("g485 paired: %s", e)
        bar.advance("codec throughput")
        try:
            res["codec"] = codec_throughput(runner)
        except Exception as e:
            log.warning("codec throughput: %s", e)
        bar.advance("issue-24 parts")
        parts = issue24.part_rows(rounds, quick, skip=args.skip_parts)
    res["targets"] = [t.as_dict() for t in issue24.own_rows(res) + parts]
    res["loadavg_after"] = loadavg()
    res["wall_s"] = time.monotonic() - t_start
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(res, indent=1))
    table = markdown(res)
    (out / "table.md").write_text(table + "\n")
    made = plots(res, out) if plotting else []
    print(table)
    print(f"\nbench: wrote {out}/results.json, table.md"
          + (f", {', '.join(made)}" if made else " (no plots: matplotlib missing)")
          + f" in {res['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
