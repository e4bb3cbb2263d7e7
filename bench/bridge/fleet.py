"""The bridge in a fleet (issue 37's bench row): many Bridge objects through a chain of brokers.

Brokers: two edge mosquittos (``edge-a`` preferred, ``edge-b``), both bridged to a
``site`` mosquitto, bridged to a ``core`` one (mosquitto's own bridges, QoS 1,
persistent sessions, persistence on). ``bridges`` Bridge objects (in this process,
each its own outbox) have the ``[[broker]]`` list edge-a, edge-b; each publishes
``rows`` rx rows, half before and half after edge-a is stopped (failover to edge-b).
A QoS 1 consumer at the core counts every row by (host, seq): lost, duplicated,
the latency from ``Bridge.rx`` to the consumer (p50/p99) and the messages/s; the
failover time of each bridge (edge-a stopped -> connected to edge-b). The same rows
through one bridge alone (no failover) are the baseline.

    python -m bench.bridge.fleet                           # 50 bridges x 200 rows
    python -m bench.bridge.fleet --bridges 10 --rows 100 --json out.json

From the bench runner (full run only, never ``--quick``): ``targets(rounds=...)``.
Needs paho-mqtt and Debian's mosquitto.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:   # for ``bench`` when run as a file
    sys.path.append(str(ROOT))

from bench import use_installed_fap_py  # noqa: E402
from bench.servers import Mosquitto  # noqa: E402
from bench.targets import Target, table  # noqa: E402

use_installed_fap_py()

log = logging.getLogger("bench.bridge.fleet")

FAILOVER_MAX = 5.0   #: seconds: the issue's failover target
WAIT = 120.0         #: seconds: the longest wait for the consumer to have every row


class ChainBroker(Mosquitto):
    """bench.servers.Mosquitto with a mosquitto bridge section towards ``remote`` (a port)."""

    def __init__(self, workdir: str, name: str, remote: Optional[int] = None) -> None:
        super().__init__(workdir)
        if remote is not None:
            with open(self.conf, "a") as f:
                f.write("\n".join([f"connection {name}", f"address 127.0.0.1:{remote}", "topic fap/# out 1",
                                   "cleansession false", f"remote_clientid {name}", "keepalive_interval 5",
                                   "restart_timeout 1", "bridge_protocol_version mqttv311",
                                   "notifications false"]) + "\n")


class Consumer:
    """A QoS 1 subscriber at the core: distinct rows by (host, seq), their latency."""

    def __init__(self, port: int) -> None:
        import paho.mqtt.client as mqtt

        self.lock = threading.Condition()
        self.seen: Dict[Tuple[str, int], float] = {}
        self.dups = 0
        self.latency: List[float] = []
        self.t_last = 0.0
        self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="fleet-consumer", clean_session=False)
        ready = threading.Event()
        self.c.on_connect = lambda c, u, f, rc, p: c.subscribe("fap/+/+/rx", 1)
        self.c.on_subscribe = lambda *a: ready.set()
        self.c.on_message = self._on_message
        self.c.max_inflight_messages_set(1000)
        self.c.connect("127.0.0.1", port)
        self.c.loop_start()
        if not ready.wait(30):
            raise RuntimeError("the consumer could not subscribe at the core")

    def _on_message(self, c: Any, u: Any, m: Any) -> None:
        now = time.time()
        d = json.loads(m.payload)
        with self.lock:
            key = (d["host"], d["seq"])
            if key in self.seen:
                self.dups += 1
                return
            self.seen[key] = now
            self.latency.append(now - d["t0"])
            self.t_last = now
            self.lock.notify_all()

    def wait(self, n: int, timeout: float) -> bool:
        with self.lock:
            return self.lock.wait_for(lambda: len(self.seen) >= n, timeout)

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def _config(ports: List[int], state_dir: str, host: str) -> Any:
    from fap_py.bridge.config import from_dict

    return from_dict({"broker": [{"url": f"mqtt://127.0.0.1:{p}", "reconnect_min": 0.05, "reconnect_max": 0.5,
                                  "connect_timeout": 2.0, "keepalive": 5} for p in ports],
                      "bridge": {"host": host, "state_dir": state_dir, "stats_interval": 3600},
                      "failover": {"attempts": 1, "failback": False},
                      "bus": [{"name": "line1", "port": "/dev/null", "protocol": "fap", "slaves": [1],
                               "reopen_interval": 3600}]})


def _send(bridges: List[Any], first: int, count: int) -> None:
    """``count`` rows from every bridge, interleaved (row by row across the bridges)."""
    for i in range(first, first + count):
        for b in bridges:
            b.rx("line1", 1, {"data": f"{i:06x}", "t0": time.time()})


def _pct(values: List[float], q: float) -> Optional[float]:
    if not values:
        return None
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))]


def run(n_bridges: int, rows: int, workdir: str, failover: bool = True) -> Dict[str, Any]:
    """One run: ``n_bridges`` bridges x ``rows`` rows through the chain (failover midway)."""
    from fap_py.bridge import Bridge

    core = ChainBroker(f"{workdir}/core", "core")
    with core:
        site = ChainBroker(f"{workdir}/site", "site-core", core.port)
        with site:
            edge_a = ChainBroker(f"{workdir}/edge-a", "edge-a-site", site.port)
            edge_b = ChainBroker(f"{workdir}/edge-b", "edge-b-site", site.port)
            with edge_a, edge_b:
                consumer = Consumer(core.port)
                bridges = [Bridge(_config([edge_a.port, edge_b.port], f"{workdir}/st{i}", f"b{i:03d}"))
                           for i in range(n_bridges)]
                try:
                    for b in bridges:
                        b.start()
                    for b in bridges:
                        if not b.wait_connected(60):
                            raise RuntimeError(f"bridge {b.config.host} did not connect")
                    t0 = time.time()
                    half = rows // 2 if failover else rows
                    _send(bridges, 0, half)
                    fo: List[float] = []
                    if failover:
                        consumer.wait(n_bridges * half, WAIT)   # the first half through, then the fault
                        stopped = time.monotonic()

                        def watch() -> None:   # each bridge's failover, while the rows go on
                            pending = set(range(n_bridges))
                            while pending and time.monotonic() < stopped + WAIT:   # bounded polling
                                for i in list(pending):
                                    link = bridges[i].link
                                    if link.connected and link.broker_index == 1:
                                        fo.append(time.monotonic() - stopped)
                                        pending.discard(i)
                                time.sleep(0.005)

                        watcher = threading.Thread(target=watch, daemon=True)
                        watcher.start()
                        edge_a.stop()
                        _send(bridges, half, rows - half)
                        watcher.join(WAIT)
                    ok = consumer.wait(n_bridges * rows, WAIT)
                    for b in bridges:
                        b.link.drain(10)
                    with consumer.lock:
                        got = len(consumer.seen)
                        lat = list(consumer.latency)
                        t_last, dups = consumer.t_last, consumer.dups
                    counted = sum(b.not_stored + b.store.dropped + b.link.refused_total for b in bridges)
                finally:
                    for b in bridges:
                        b.stop(drain=1)
                    consumer.close()
    expected = n_bridges * rows
    return {"bridges": n_bridges, "rows_each": rows, "expected": expected, "delivered": got,
            "lost": expected - got, "counted_losses": counted, "duplicates": dups, "complete": ok,
            "msgs_per_s": got / (t_last - t0) if t_last > t0 else None,
            "latency_p50_ms": None if not lat else 1000 * statistics.median(lat),
            "latency_p99_ms": None if not lat else 1000 * (_pct(lat, 0.99) or 0),
            "failover_s": {"n": len(fo), "median": statistics.median(fo) if fo else None,
                           "max": max(fo) if fo else None, "not_failed_over": n_bridges - len(fo) if failover
                           else 0}}


def measure(n_bridges: int = 50, rows: int = 200) -> Dict[str, Any]:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="fap-fleet-") as d:
        fleet = run(n_bridges, rows, f"{d}/fleet", failover=True)
    with tempfile.TemporaryDirectory(prefix="fap-fleet-one-") as d:
        single = run(1, rows * n_bridges, f"{d}/one", failover=False)   # the same rows, one bridge
    return {"fleet": fleet, "single": single, "load_before": load, "load_after": os.getloadavg()[0]}


def to_targets(res: Dict[str, Any]) -> List[Target]:
    f, s = res["fleet"], res["single"]
    note = (f"{f['bridges']} bridges x {f['rows_each']} rows via edge -> site -> core, edge-a stopped midway: "
            f"{f['delivered']}/{f['expected']} at the core, {f['duplicates']} duplicates, "
            f"{f['msgs_per_s'] or 0:.0f} msg/s, p50 {f['latency_p50_ms'] or 0:.0f} ms, "
            f"p99 {f['latency_p99_ms'] or 0:.0f} ms; one bridge alone: {s['msgs_per_s'] or 0:.0f} msg/s, "
            f"p50 {s['latency_p50_ms'] or 0:.0f} ms, p99 {s['latency_p99_ms'] or 0:.0f} ms; "
            f"load {res.get('load_before', 0):.1f} -> {res.get('load_after', 0):.1f}")
    fo = f["failover_s"]
    return [Target("fleet-lost", "fleet: 0 rows lost through a 3-broker chain with a failover",
                   float(f["lost"]), 0.0, False, "rows", note),
            Target("fleet-failover", f"fleet: every bridge fails over within {FAILOVER_MAX:g} s",
                   fo["max"] if fo["not_failed_over"] == 0 else None, FAILOVER_MAX, False, "s",
                   f"median {fo['median'] or 0:.2f} s over {fo['n']} bridges"
                   + (f"; {fo['not_failed_over']} never did" if fo["not_failed_over"] else ""))]


def targets(rounds: int = 1, bridges: int = 50, rows: int = 200) -> List[Target]:
    """The bench runner's entry (full run only): the fleet rows."""
    return to_targets(measure(bridges, rows))


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bridges", type=int, default=50)
    ap.add_argument("--rows", type=int, default=200, help="rows per bridge")
    ap.add_argument("--json", metavar="FILE", help="write the raw results here")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("fap_py").setLevel(logging.ERROR)   # 50 bridges' connect and failover lines
    res = measure(args.bridges, args.rows)
    for name in ("fleet", "single"):
        print(f"{name}: {json.dumps(res[name])}")
    rows = to_targets(res)
    print()
    print(table(rows), end="")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(res, f, indent=1)
    return 0 if all(t.met for t in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
