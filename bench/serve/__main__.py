"""``python -m bench.serve``: what `fap serve` costs and how it shares the bus.

Rows (bench/PERFORMANCE.md, "fap serve"):

* **added latency**: exec transactions (4-byte payload) from one client, direct on the
  master port vs through a `fap serve` daemon on that port (a Unix socket), on a paced
  virtual bus at 115200 and 1,000,000 baud; the slave is `fap exec slave` in its own
  process, the daemon another; p50 / p99 of each transaction's round trip and their
  difference;
* **8 clients**: 8 client processes, weights 1,1,1,1,2,2,4,4, each keeping 4
  transactions queued (asyncio tasks on one DaemonMaster), for a fixed time: total
  transactions/s against one direct master, each client's share of wire time against
  its weight's share, misdelivered answers (every request carries a tag the slave
  echoes) and late replies.

    python -m bench.serve            # about 1 minute
    python -m bench.serve --quick    # a smoke run
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

    def daemon(self) -> subprocess.Popen:
        sock = os.path.join(self.tmp, "bus.sock")
        d = subprocess.Popen(FAP + ["serve", "--protocol", "exec", "--port", self.vb.paths[0], *NONE,
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


def _latencies(port: str, baud: int, n: int) -> List[float]:
    from fap_py.execasync import RS485, Master, RS485Mode

    kw = {} if port.startswith("fapd://") else {"rs485": RS485(mode=RS485Mode.NONE)}
    out = []
    with Master(port, baud, timeout=0.2, retries=1, **kw) as m:
        for i in range(n):
            t0 = time.perf_counter()
            m.transact(5, i.to_bytes(4, "big"))
            out.append(time.perf_counter() - t0)
    return out


def _pct(v: List[float], q: float) -> float:
    s = sorted(v)
    return s[min(len(s) - 1, int(q * len(s)))]


def latency_rows(n: int) -> List[Dict[str, Any]]:
    rows = []
    for baud in (115200, 1000000):
        bus = Bus(baud)
        try:
            direct = _latencies(bus.vb.paths[0], baud, n)
            d = bus.daemon()
            try:
                served = _latencies(bus.url, baud, n)
            finally:
                d.terminate()
                d.wait(10)
        finally:
            bus.close()
        rows.append({"baud": baud, "n": n,
                     "direct_p50_us": _pct(direct, .5) * 1e6, "direct_p99_us": _pct(direct, .99) * 1e6,
                     "daemon_p50_us": _pct(served, .5) * 1e6, "daemon_p99_us": _pct(served, .99) * 1e6})
        r = rows[-1]
        r["added_p50_us"] = r["daemon_p50_us"] - r["direct_p50_us"]
        r["added_p99_us"] = r["daemon_p99_us"] - r["direct_p99_us"]
    return rows


def fairness_row(baud: int, seconds: float) -> Dict[str, Any]:
    from fap_py.serve import status

    bus = Bus(baud)
    try:
        direct = _latencies(bus.vb.paths[0], baud, 300)
        d = bus.daemon()
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
            st0 = status(bus.url)
            time.sleep(seconds * 0.5)
            st = status(bus.url)
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
    return {"baud": baud, "seconds": seconds, "transactions": done,
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
    args = ap.parse_args()
    use_installed_fap_py()
    n, secs = (200, 3.0) if args.quick else (2000, 10.0)
    secs = args.seconds or secs
    res = {"latency": [] if args.only_clients else latency_rows(n),
           "fairness": [fairness_row(b, secs) for b in (115200, 1000000)], "load": os.getloadavg()}
    if args.json:
        print(json.dumps(res))
        return 0
    print("| baud | n | direct p50 / p99 µs | via daemon p50 / p99 µs | added p50 / p99 µs |")
    print("|---|---|---|---|---|")
    for r in res["latency"]:
        print(f"| {r['baud']} | {r['n']} | {r['direct_p50_us']:.0f} / {r['direct_p99_us']:.0f} | "
              f"{r['daemon_p50_us']:.0f} / {r['daemon_p99_us']:.0f} | "
              f"{r['added_p50_us']:.0f} / {r['added_p99_us']:.0f} |")
    print()
    print("| baud | s | transactions/s (8 clients) | one direct master /s | misdelivered | failed | late |"
          " wire-time share got/want (weights 1,1,1,1,2,2,4,4) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in res["fairness"]:
        sh = " ".join(f"{s['got']:.3f}/{s['want']:.3f}" for s in r["shares"])
        print(f"| {r['baud']} | {r['seconds']:.0f} | {r['per_s']:.0f} | {r['direct_per_s']:.0f} | "
              f"{r['misdelivered']} of {r['transactions']} | {r['failed']} | {r['late']} | {sh} |")
    print(f"\nload average {res['load']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
