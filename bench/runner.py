"""The runner of ``python -m bench``: one exchange benchmark (a C or a Python
client/server pair on a virtual bus), the series of them and the other
measured parts (scale, Python overhead, codec throughput, the profile).

Imports the kinds, statistics and perf probes; the report never imports it.
The Python clients and servers live in ``bench/g485/bench_g485.py`` and
``bench/fap_py/bench_fap_py.py`` (programs as well as modules): :func:`suite_paths`
puts their folders on ``sys.path``.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

from bench import ROOT, syscalls
from bench.kinds import BASE, PEER_HELP, PEER_MODULES, PY_KINDS, is_c, limit
from bench.stats import pct, proc_cpu, proc_wakeups, summary, turnarounds

log = logging.getLogger("bench")


def suite_paths() -> None:
    """bench_g485 and bench_fap_py importable by name (as their own programs do)."""
    for sub in ("g485", "fap_py"):
        p = str(ROOT / "bench" / sub)
        if p not in sys.path:
            sys.path.insert(0, p)


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
        kinds: Dict[str, syscalls.Probe] = {}
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
                                   stdout=subprocess.PIPE, text=True, stderr=sp.stderr if sp else None,
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
                                       stdout=subprocess.PIPE, text=True, stderr=cp.stderr if cp else None,
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
            for pr in kinds.values():
                pr.relay_stderr()           # bench_wire's own lines, without perf's
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

def available(runner: Runner, wanted: Sequence[str]) -> Tuple[List[str], Dict[str, str]]:
    """Of the ``wanted`` kinds, those that can run here, and the missing peers
    with how to get them (only peers this run would have measured)."""
    missing: Dict[str, str] = {}
    if "modbus" in wanted:
        probe = subprocess.run([str(runner.exe), "serve", "modbus", "/nonexistent"],
                               capture_output=True, text=True)
        if probe.returncode == 2:
            missing["modbus"] = PEER_HELP["modbus"]
    for kind, mod in PEER_MODULES.items():
        if kind in wanted and importlib.util.find_spec(mod) is None:
            missing[kind] = PEER_HELP[kind]
    return [k for k in wanted if k not in missing], missing


def measure_series(runner: Runner, kind: str, baud: int, rounds: int, seconds: float) -> Dict[str, Any]:
    runs = []
    for r in range(rounds):
        cap = r == 0 and baud != 0
        try:
            if is_c(kind):
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


def python_overhead(args: argparse.Namespace, quick: bool) -> Dict[str, Any]:
    """fap_py against the C API on one unpaced bus (bench/fap_py).

    Round trips (issue 24's target) are interleaved C / fap_py / asyncio runs,
    the median of the per-pair ratios (``bench_fap_py.paired``, the same
    measurement as ``bench_fap_py.py --paired``); each row also carries the
    master's poll turns per round trip and the load average. ``calls`` (the
    binding's cost per call, no wire) is the median of 3 interleaved pairs
    (``quick``: 3 round-trip pairs of 200, one calls pair of 2000).
    """
    import statistics

    import bench_fap_py as fp

    exe = args.build_dir / "bench" / "fap_py" / "bench_fapx_c"
    bus = fp.BusProcess(2, 0)
    out: Dict[str, Any] = {}
    try:
        n = 200 if quick else fp.PAIR_COUNT
        pr = fp.paired(exe, bus.paths, pairs=3 if quick else fp.PAIRS, count=n, size=16)
        common = {"pairs": pr["pairs"], "dropped": len(pr["dropped"]), "count": n,
                  "load_before": pr["load_before"],
                  "load_after": pr["load_after"], "c_polls": pr["polls"]["c"]}
        out["round-trip"] = dict(
            common, c_rate=pr["rate"]["c"], py_rate=pr["rate"]["py"], c_cpu_us=pr["cpu_us"]["c"],
            py_cpu_us=pr["cpu_us"]["py"], py_polls=pr["polls"]["py"], ratio=pr["ratio"],
            ratio_min=pr["ratio_min"], ratio_max=pr["ratio_max"],
            ratios=[p["py"]["rate"] / p["c"]["rate"] for p in pr["per_pair"]])
        nc = 2000 if quick else 10000
        calls = [(fp.run_c(exe, bus.paths, "calls", nc, 16),
                  fp.run_py(bus.paths, "calls", nc, 16)) for _ in range(1 if quick else 3)]
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


def codec_throughput(runner: Runner, seconds: float = 0.3) -> Dict[str, Any]:
    """Payload MB/s through the encoders and decoders, C (bench_wire codec)
    and Python (fap_py: exec async and mikroC through cffi, G485 pure)."""
    out: Dict[str, Any] = {"c": json.loads(subprocess.run(
        [str(runner.exe), "codec"], capture_output=True, text=True, check=True).stdout)}
    from fap_py import execasync, mikroc
    from fap_py.g485 import codec as g

    def timed(fn: Any, payload: int) -> float:
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
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

