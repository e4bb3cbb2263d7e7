"""``python -m bench.serve``: what `fap serve` costs and how it shares the bus.

Rows (bench/PERFORMANCE.md, "fap serve"):

* **added latency**: exec transactions (4-byte payload) from one client, direct on the
  master port vs through a `fap serve` daemon on that port (a Unix socket), on a paced
  virtual bus at 115200 and 1,000,000 baud; the slave is `fap exec slave` in its own
  process, the daemon another; p50 / p99 of each transaction's round trip and their
  difference. Direct and through the daemon alternate transaction by transaction (two
  identical buses, each with its slave), so both see the same load of this shared
  machine; the daemon's CPU time per transaction (/proc schedstat) is the figure that
  load does not move;
* **8 clients**: 8 client processes, weights 1,1,1,1,2,2,4,4, each keeping 4
  transactions queued (asyncio tasks on one DaemonMaster), for a fixed time: total
  transactions/s against one direct master, each client's share of wire time against
  its weight's share, misdelivered answers (every request carries a tag the slave
  echoes) and late replies.

    python -m bench.serve            # about 1 minute
    python -m bench.serve --quick    # a smoke run
    python -m bench.serve --compare /path/to/old/venv/bin/python   # and another fap_py's daemon
"""
from __future__ import annotations

import argparse
import json
import os
import select
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any, Dict, List

from bench import use_installed_fap_py

FAP = [sys.executable, "-I", "-m", "fap_py"]
NONE = ["--rs485", "none"]
WEIGHTS = (1, 1, 1, 1, 2, 2, 4, 4)

CLIENT = r"""
import asyncio, json, sys, time
from fap_py.execasync import Master
url, cid, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
ok = bad = fail = 0
async def main():
    global ok, bad, fail
    async with Master(url, timeout=0.2, retries=1) as m:
        await m.atransact(5, b"hello")           # connected and served once: ready
        print("ready", flush=True)
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)   # go
        end = time.monotonic() + seconds
        async def worker(k):
            global ok, bad, fail
            i = 0
            while time.monotonic() < end:
                tag = f"{cid}:{k}:{i}".encode(); i += 1
                try:
                    r = await m.atransact(5, tag)
                except Exception:
                    fail += 1; continue
                ok += r == tag; bad += r != tag
        await asyncio.gather(*[worker(k) for k in range(4)])
asyncio.run(main())
print(json.dumps({"ok": ok, "bad": bad, "fail": fail}))
"""


def _ready(p: subprocess.Popen, what: str, timeout: float = 15.0) -> Dict[str, Any]:
    assert p.stdout is not None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        r, _, _ = select.select([p.stdout], [], [], max(0.0, end - time.monotonic()))
        if not r:
            break
        line = p.stdout.readline()
        if not line:
            break
        obj = json.loads(line)
        if obj.get("event") == "ready":
            return obj
    p.kill()
    raise RuntimeError(f"{what} never got ready: {p.communicate()}")


class Bus:
    """A paced virtual bus with `fap exec slave` (node 5, echo) on port 1."""

    def __init__(self, baud: int) -> None:
        from fap_py.vbus import VirtualBus

        self.vb = VirtualBus(ports=2, baud=baud)
        self.baud = baud
        self.slave = subprocess.Popen(FAP + ["exec", "slave", "--port", self.vb.paths[1], *NONE,
                                             "--baud", str(baud), "--node", "5", "--json"],
                                      stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                      bufsize=1)
        _ready(self.slave, "the slave")
        threading_drain(self.slave)
        self.tmp = tempfile.mkdtemp(prefix="bench-serve-")

    def daemon(self, python: str = sys.executable) -> subprocess.Popen:
        sock = os.path.join(self.tmp, "bus.sock")
        d = subprocess.Popen([python, *FAP[1:], "serve", "--protocol", "exec", "--port", self.vb.paths[0], *NONE,
                                    "--baud", str(self.baud), "--listen", f"unix:{sock}",
                                    "--lock-dir", self.tmp, "--queue", "64", "--json"],
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)
        _ready(d, "fap serve")
        self.url = "fapd://" + sock
        return d

    def close(self) -> None:
        self.slave.terminate()
        self.slave.wait(10)
        self.vb.close()


def threading_drain(p: subprocess.Popen) -> None:
    """Read a child's stdout to its end in the background (its pipe never fills)."""
    import threading

    def drain() -> None:
        assert p.stdout is not None
        for _ in p.stdout:
            pass
    threading.Thread(target=drain, daemon=True).start()


def _master(port: str, baud: int) -> Any:
    from fap_py.execasync import RS485, Master, RS485Mode

    kw = {} if port.startswith("fapd://") else {"rs485": RS485(mode=RS485Mode.NONE)}
    return Master(port, baud, timeout=0.2, retries=1, **kw)


def _latencies(port: str, baud: int, n: int) -> List[float]:
    out = []
    with _master(port, baud) as m:
        for i in range(n):
            t0 = time.perf_counter()
            m.transact(5, i.to_bytes(4, "big"))
            out.append(time.perf_counter() - t0)
    return out


def _cpu_s(pid: int) -> float:
    """A process's CPU time so far (s): /proc/PID/schedstat, ns (Linux)."""
    with open(f"/proc/{pid}/schedstat") as f:
        return int(f.read().split()[0]) / 1e9


def _pct(v: List[float], q: float) -> float:
    s = sorted(v)
    return s[min(len(s) - 1, int(q * len(s)))]


def latency_rows(n: int, pythons: Dict[str, str]) -> List[Dict[str, Any]]:
    """Per baud: one direct master and one client of each daemon (``pythons``: label ->
    the interpreter that runs it), each on its own identical bus, taking turns a
    transaction each."""
    rows = []
    for baud in (115200, 1000000):
        buses = {"direct": Bus(baud), **{k: Bus(baud) for k in pythons}}
        daemons: Dict[str, subprocess.Popen] = {}
        try:
            for k, py in pythons.items():
                daemons[k] = buses[k].daemon(py)
            masters = {"direct": _master(buses["direct"].vb.paths[0], baud),
                       **{k: _master(buses[k].url, baud) for k in pythons}}
            times: Dict[str, List[float]] = {k: [] for k in masters}
            cpu0 = {k: _cpu_s(d.pid) for k, d in daemons.items()}
            try:
                for i in range(n):
                    payload = i.to_bytes(4, "big")
                    for k, m in masters.items():
                        t0 = time.perf_counter()
                        m.transact(5, payload)
                        times[k].append(time.perf_counter() - t0)
            finally:
                for m in masters.values():
                    m.close()
            cpu = {k: _cpu_s(d.pid) - cpu0[k] for k, d in daemons.items()}
        finally:
            for d in daemons.values():
                d.terminate()
                d.wait(10)
            for b in buses.values():
                b.close()
        direct = times["direct"]
        row: Dict[str, Any] = {"baud": baud, "n": n, "load": os.getloadavg()[0],
                               "direct_p50_us": _pct(direct, .5) * 1e6, "direct_p99_us": _pct(direct, .99) * 1e6}
        for k in pythons:
            v = times[k]
            row[k] = {"p50_us": _pct(v, .5) * 1e6, "p99_us": _pct(v, .99) * 1e6,
                      "added_p50_us": (_pct(v, .5) - _pct(direct, .5)) * 1e6,
                      "added_p99_us": (_pct(v, .99) - _pct(direct, .99)) * 1e6,
                      "cpu_us": cpu[k] / n * 1e6}
        rows.append(row)
    return rows


def fairness_row(baud: int, seconds: float, python: str = sys.executable) -> Dict[str, Any]:
    from fap_py.serve import status

    bus = Bus(baud)
    try:
        direct = _latencies(bus.vb.paths[0], baud, 300)
        d = bus.daemon(python)
        try:
            procs = [subprocess.Popen([sys.executable, "-I", "-c", CLIENT, f"{bus.url}?weight={w}&name=c{i}",
                                       str(i), str(seconds)], stdout=subprocess.PIPE,
                                      stdin=subprocess.PIPE, text=True)
                     for i, w in enumerate(WEIGHTS)]
            for p in procs:                  # every client connected before any starts
                assert p.stdout is not None and p.stdout.readline().strip() == "ready"
            for p in procs:
                assert p.stdin is not None
                p.stdin.write("go\n")
                p.stdin.flush()
            time.sleep(seconds * 0.3)        # a bench, not a test: sample while all are busy
            st0, cpu0 = status(bus.url), _cpu_s(d.pid)
            time.sleep(seconds * 0.5)
            st, cpu1 = status(bus.url), _cpu_s(d.pid)
            results = [json.loads(p.communicate(timeout=seconds + 60)[0]) for p in procs]
            total = status(bus.url)
        finally:
            d.terminate()
            d.wait(10)
    finally:
        bus.close()
    before = {c["name"]: c["wire_time"] for c in st0["clients"]}
    used = {c["name"]: c["wire_time"] - before.get(c["name"], 0.0) for c in st["clients"]}
    wsum, usum = sum(WEIGHTS), sum(used.get(f"c{i}", 0.0) for i in range(len(WEIGHTS))) or 1.0
    shares = [(w / wsum, used.get(f"c{i}", 0.0) / usum) for i, w in enumerate(WEIGHTS)]
    done = sum(r["ok"] + r["bad"] for r in results)
    window = st["totals"]["transactions"] - st0["totals"]["transactions"]
    return {"baud": baud, "seconds": seconds, "transactions": done, "load": os.getloadavg()[0],
            "cpu_us": (cpu1 - cpu0) / max(window, 1) * 1e6,
            "per_s": done / seconds, "direct_per_s": 1 / statistics.mean(direct),
            "misdelivered": sum(r["bad"] for r in results),
            "failed": sum(r["fail"] for r in results),
            "late": total["totals"]["late"],
            "shares": [{"weight": w, "want": round(a, 3), "got": round(b, 3)}
                       for w, (a, b) in zip(WEIGHTS, shares)]}


def main() -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.serve")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--seconds", type=float, help="length of the 8-client runs (default 10; 3 quick)")
    ap.add_argument("--only-clients", action="store_true",
                    help="only the 8-client rows (a long --seconds run: the transactions count)")
    ap.add_argument("--compare", metavar="PYTHON",
                    help="also run the daemon with this interpreter (another fap_py installed: "
                         "an older one), in the same run; the clients are this fap_py")
    args = ap.parse_args()
    use_installed_fap_py()
    n, secs = (200, 3.0) if args.quick else (2000, 10.0)
    secs = args.seconds or secs
    pythons = {"daemon": sys.executable, **({"compare": args.compare} if args.compare else {})}
    res = {"latency": [] if args.only_clients else latency_rows(n, pythons),
           "fairness": [dict(fairness_row(b, secs, py), daemon=k)
                        for b in (115200, 1000000) for k, py in pythons.items()],
           "load": os.getloadavg()}
    if args.json:
        print(json.dumps(res))
        return 0
    print("| baud | n | daemon | direct p50 / p99 µs | via daemon p50 / p99 µs | added p50 / p99 µs |"
          " daemon CPU µs / transaction | load |")
    print("|---|---|---|---|---|---|---|---|")
    for r in res["latency"]:
        for k in pythons:
            d = r[k]
            print(f"| {r['baud']} | {r['n']} | {k} | {r['direct_p50_us']:.0f} / {r['direct_p99_us']:.0f} | "
                  f"{d['p50_us']:.0f} / {d['p99_us']:.0f} | {d['added_p50_us']:.0f} / {d['added_p99_us']:.0f} | "
                  f"{d['cpu_us']:.0f} | {r['load']:.1f} |")
    print()
    print("| baud | s | daemon | transactions/s (8 clients) | one direct master /s | misdelivered | failed |"
          " late | daemon CPU µs / transaction | load | wire-time share got/want (weights 1,1,1,1,2,2,4,4) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in res["fairness"]:
        sh = " ".join(f"{s['got']:.3f}/{s['want']:.3f}" for s in r["shares"])
        print(f"| {r['baud']} | {r['seconds']:.0f} | {r['daemon']} | {r['per_s']:.0f} | {r['direct_per_s']:.0f} | "
              f"{r['misdelivered']} of {r['transactions']} | {r['failed']} | {r['late']} | {r['cpu_us']:.0f} | "
              f"{r['load']:.1f} | {sh} |")
    print(f"\nload average {res['load']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
