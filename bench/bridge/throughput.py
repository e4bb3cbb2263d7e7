"""Does ``fap bridge`` keep pace with the bus? (issue 24's bridge target)

One round at one paced baud rate is two runs on the same kind of bus, back to back:

* **bus**: a FAP master (``fap_py.fap.Master``, in this process) and ``slaves`` FAP
  slaves flooding it (each sends as fast as its transmit queue takes messages) on a
  ``VirtualBus`` paced at ``baud``: the messages/s the *bus* delivers to a master;
* **bridge**: the same bus and flood with ``fap bridge`` (its own process) as the master,
  a private mosquitto and a QoS 1 consumer: the messages/s that reach the *consumer*,
  and how many were lost (sent, never received) or duplicated (one bus message published
  under two ``seq``).

Both rates are counted the same way, at the last receiver: distinct messages over the
time from the first to the last arrival. The target: forwarded >= 95 % of the bus's
rate, 0 lost, 0 duplicated, medians of ``rounds`` rounds, the load average recorded
with every number (the machine is shared).

    python -m bench.bridge.throughput                   # 115200 and 1 Mbaud, 3 rounds, table
    python -m bench.bridge.throughput --json out.json   # also the raw rounds

From the bench runner: ``from bench.bridge.throughput import targets; rows = targets()``
(a list of ``bench.targets.Target``). Needs paho-mqtt and Debian's mosquitto.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

ROOT = Path(__file__).resolve().parents[2]
# The checkout's fap_py/ has no compiled _native: use the installed fap_py (as bench/__main__).
if str(ROOT) not in sys.path:   # for ``bench`` when run as a file
    sys.path.append(str(ROOT))

from bench import use_installed_fap_py  # noqa: E402
from bench.targets import Target, table  # noqa: E402

use_installed_fap_py()

log = logging.getLogger("bench.bridge")

MSG = struct.Struct("<BIQ")   # slave id, counter, send time (time.time_ns): 13 bytes of DATA
BAUDS = (115200, 1_000_000)
SHARE = 0.95                  # the target: forwarded / delivered


def load_avg() -> float:
    """The 1-minute load average (recorded beside every number)."""
    return os.getloadavg()[0]


class Arrivals:
    """Distinct messages by (slave, counter), with the first and last arrival times."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.keys: Dict[Tuple[int, int], set] = {}   # message -> the bridge seqs it came under
        self.raw = 0
        self.t_first = 0.0
        self.t_last = 0.0
        self.times: List[Tuple[float, float]] = []   # distinct messages: (bridge's rx time, arrival)

    def add(self, data: bytes, seq: Optional[int] = None, rx_ts: float = 0.0) -> None:
        now = time.time()   # wall clock: compared with the bridge's stats timestamps
        sid, n, _ = MSG.unpack(data)
        with self.lock:
            self.raw += 1
            seqs = self.keys.get((sid, n))
            if seqs is None:
                seqs = self.keys[(sid, n)] = set()
                self.t_first = self.t_first or now
                self.t_last = now
                self.times.append((rx_ts, now))
            if seq is not None:
                seqs.add(seq)

    def count(self) -> int:
        with self.lock:
            return len(self.keys)

    def rate(self) -> float:
        with self.lock:
            span = self.t_last - self.t_first
            return (len(self.keys) - 1) / span if span > 0 else 0.0

    def paced(self, a: float, b: float) -> Tuple[float, float, int]:
        """The messages the bridge took from the bus in the wall-clock window [a, b]:
        their rate into the bridge, their rate out to this consumer, and how many.
        Same messages both ways, so the bridge's latency does not bias the ratio."""
        with self.lock:
            sel = [t for t in self.times if a <= t[0] <= b]
        if len(sel) < 2:
            return 0.0, 0.0, len(sel)
        span_in = max(t[0] for t in sel) - min(t[0] for t in sel)
        span_out = max(t[1] for t in sel) - min(t[1] for t in sel)
        n = len(sel) - 1
        return n / span_in if span_in > 0 else 0.0, n / span_out if span_out > 0 else 0.0, len(sel)

    def duplicated(self) -> int:
        with self.lock:
            return sum(max(0, len(s) - 1) for s in self.keys.values())


def _flood(slaves: List[Any], seconds: float) -> int:
    """Every slave sends numbered messages as fast as its transmit queue takes them."""
    sent = [0] * len(slaves)
    until = time.monotonic() + seconds

    def run(i: int) -> None:
        s = slaves[i]
        while time.monotonic() < until:
            s.send(MSG.pack(s.id, sent[i], time.time_ns()), timeout=None)
            sent[i] += 1

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(slaves))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(sent)


def _wait(cond: Any, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)   # polling a counter in a benchmark, not test synchronisation
    return cond()


def bus_run(baud: int, n_slaves: int, seconds: float) -> Dict[str, Any]:
    """The bus alone: a fap_py master receives the flood."""
    from fap_py.errors import FapTimeoutError
    from fap_py.fap import Master, Slave
    from fap_py.vbus import VirtualBus

    ids = list(range(1, n_slaves + 1))
    got = Arrivals()
    load0 = load_avg()
    with VirtualBus(n_slaves + 1, baud=baud) as vbus, \
            Master(vbus.paths[0], baud, slaves=ids, id_cycle=0.2, data_done_timeout=0.5) as master:
        slaves = [Slave(vbus.paths[i + 1], baud, id=sid) for i, sid in enumerate(ids)]
        stop = threading.Event()

        def reader() -> None:
            while not stop.is_set():
                try:
                    got.add(master.recv(0.2).data)
                except FapTimeoutError:
                    continue

        t = threading.Thread(target=reader, daemon=True)
        t.start()
        try:
            master.wait_active(ids, timeout=10)
            sent = _flood(slaves, seconds)
            _wait(lambda: got.count() >= sent, 10)
        finally:
            stop.set()
            t.join(5)
            for s in slaves:
                s.close()
    return {"rate": got.rate(), "sent": sent, "received": got.count(), "lost": sent - got.count(),
            "load": round((load0 + load_avg()) / 2, 2)}


_CONFIG = """[bridge]
host = "bench"
topic_prefix = "bench"
state_dir = "state"
stats_interval = 0.25

[broker]
url = "mqtt://127.0.0.1:{port}"

[[bus]]
name = "line"
port = "{path}"
protocol = "fap"
baud = {baud}
slaves = {ids}
id_cycle = 0.2
data_done_timeout = 0.5
"""


def _epoch(ts: str) -> float:
    """The bridge's RFC 3339 UTC timestamp as Unix time."""
    import calendar

    whole, frac = ts.rstrip("Z").split(".")
    return calendar.timegm(time.strptime(whole, "%Y-%m-%dT%H:%M:%S")) + float("0." + frac)


def bridge_run(baud: int, n_slaves: int, seconds: float, work: str,
               profile: Optional[str] = None) -> Dict[str, Any]:
    """The same flood with ``fap bridge`` as the master; counted at an MQTT consumer.

    The bus's delivered rate comes from the bridge's own stats (the FAP engine's
    ``data_rx``, published every 0.25 s with its timestamp); the forwarded rate is the
    consumer's distinct arrivals in the same wall-clock window. ``profile``: a py-spy
    command line ending in ``--pid``, run on the bridge process during the flood."""
    import paho.mqtt.client as mqtt

    from bench.servers import Mosquitto
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    ids = list(range(1, n_slaves + 1))
    got = Arrivals()
    load0 = load_avg()
    os.makedirs(work, exist_ok=True)
    with Mosquitto(os.path.join(work, "broker")) as broker, VirtualBus(n_slaves + 1, baud=baud) as vbus:
        conf = os.path.join(work, "bridge.toml")
        with open(conf, "w") as f:
            f.write(_CONFIG.format(port=broker.port, path=vbus.paths[0], baud=baud, ids=ids))
        online = threading.Event()
        active: set = set()
        samples: List[Tuple[float, int, int]] = []   # (ts, engine data_rx, engine rx_dropped)

        def on_message(c: Any, u: Any, m: Any) -> None:
            if m.topic.endswith("/status"):
                if m.payload == b"online":
                    online.set()
                return
            doc = json.loads(m.payload)
            if m.topic.endswith("/stats"):
                eng = doc["engine"]
                samples.append((_epoch(doc["ts"]), eng.get("data_rx", 0), eng.get("rx_dropped", 0)))
            elif m.topic.endswith("/state"):
                if doc.get("state") == "active":
                    active.add(m.topic)
            else:
                got.add(bytes.fromhex(doc["data"]), doc["seq"], _epoch(doc["ts"]))

        consumer = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-consumer", clean_session=False)
        consumer.on_connect = lambda c, u, f, rc, p: c.subscribe(
            [("bench/line/+/rx", 1), ("bench/bridge/bench/status", 1), ("bench/line/+/state", 1),
             ("bench/line/stats", 1)])
        consumer.on_message = on_message
        consumer.connect("127.0.0.1", broker.port)
        consumer.loop_start()
        with open(os.path.join(work, "bridge.log"), "w") as logf:
            proc = subprocess.Popen([sys.executable, "-m", "fap_py", "bridge", "--config", conf, "--drain", "30"],
                                    stdout=logf, stderr=logf, cwd=work)
        slaves = [Slave(vbus.paths[i + 1], baud, id=sid) for i, sid in enumerate(ids)]
        spy = None
        try:
            if not online.wait(30):
                raise RuntimeError(f"the bridge never came online: {work}/bridge.log")
            _wait(lambda: len(active) == len(ids), 10)   # every slave answered its ID query
            if profile:
                spy = subprocess.Popen(profile.split() + [str(proc.pid)], stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL)
            cpu0, t0, flood_start = _cpu(proc.pid), time.monotonic(), time.time()
            sent = _flood(slaves, seconds)
            flood_end = time.time()
            # settled: a stats sample taken after the flood whose data_rx the consumer has all of
            _wait(lambda: bool(samples) and samples[-1][0] > flood_end + 0.5
                  and got.count() >= samples[-1][1] - samples[-1][2], 30)
            cpu = (_cpu(proc.pid) - cpu0) / (time.monotonic() - t0)
        finally:
            for s in slaves:
                s.close()
            proc.terminate()   # SIGTERM: the bridge drains its outbox, goes offline, exits
            if not _wait(lambda: proc.poll() is not None, 40):
                proc.kill()
            if spy is not None:
                spy.wait(30)
            consumer.loop_stop()
            consumer.disconnect()
    received = got.count()
    delivered, dropped = samples[-1][1], samples[-1][2]
    # steady state: the messages the bridge took from the bus from 1 s into the flood to its end
    rate_in, rate_out, n = got.paced(flood_start + 1.0, flood_end)
    return {"delivered": delivered, "delivered_rate": rate_in, "rate": rate_out, "window_msgs": n,
            "share": rate_out / rate_in if rate_in else 0.0,
            "sent": sent, "received": received, "lost": delivered - received, "rx_dropped": dropped,
            "wire_lost": sent - delivered, "duplicated": got.duplicated(),
            "redelivered": got.raw - received - got.duplicated(),
            "bridge_cpu": round(cpu, 3), "load": round((load0 + load_avg()) / 2, 2)}


def _cpu(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure(bauds: Tuple[int, ...] = BAUDS, rounds: int = 3, seconds: float = 8.0, slaves: int = 3,
            profile: Optional[str] = None) -> Dict[int, List[Dict[str, Any]]]:
    """``rounds`` rounds per baud, each a bus run then a bridge run (interleaved, so a change
    of the machine's load falls on both)."""
    out: Dict[int, List[Dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory(prefix="fap-bridge-bench-") as work:
        for baud in bauds:
            for r in range(rounds):
                bus = bus_run(baud, slaves, seconds)
                spy = None if profile is None else f"{profile}-{baud}-{r}.txt"
                bridge = bridge_run(baud, slaves, seconds, os.path.join(work, f"{baud}-{r}"),
                                    None if spy is None else f"py-spy record --nonblocking -r 200 -f raw -t -o {spy} --pid")
                row = {"round": r, "bus": bus, "bridge": bridge, "share": bridge["share"]}
                log.info("baud %d round %d: bus %.0f/s, bridge %.0f/s (%.1f %%), lost %d, dup %d, load %.1f",
                         baud, r, bus["rate"], bridge["rate"], 100 * row["share"], bridge["lost"],
                         bridge["duplicated"], bridge["load"])
                out.setdefault(baud, []).append(row)
    return out


def _baud_name(baud: int) -> str:
    return f"{baud // 1_000_000} Mbaud" if baud % 1_000_000 == 0 else str(baud)


def to_targets(results: Dict[int, List[Dict[str, Any]]]) -> List[Target]:
    """One target row per baud: the median share forwarded; a round that lost or
    duplicated a message makes the row missed."""
    rows = []
    for baud, rounds in results.items():
        share = statistics.median(r["share"] for r in rounds)
        lost = sum(r["bridge"]["lost"] for r in rounds)
        dup = sum(r["bridge"]["duplicated"] for r in rounds)
        wire = sum(r["bridge"]["wire_lost"] for r in rounds)
        alone = statistics.median(r["bus"]["rate"] for r in rounds)
        into = statistics.median(r["bridge"]["delivered_rate"] for r in rounds)
        out = statistics.median(r["bridge"]["rate"] for r in rounds)
        loads = [r["bridge"]["load"] for r in rounds]
        note = (f"median of {len(rounds)}: bus alone {alone:.0f} msg/s; with the bridge the bus delivered "
                f"{into:.0f} msg/s and the consumer got {out:.0f} msg/s; bridge lost {lost}, duplicated {dup} "
                f"(the loaded pty bus itself lost {wire} frames: gap timeouts); load avg "
                f"{min(loads):.1f}-{max(loads):.1f}")
        value = share * 100 if lost == 0 and dup == 0 else 0.0
        rows.append(Target(f"bridge-forward-{baud}", f"bridge forwards >= {SHARE:.0%} of the bus's msg/s "
                           f"at {_baud_name(baud)}, 0 lost, 0 duplicated", round(value, 1), SHARE * 100, True, "%",
                           note))
    return rows


def targets(rounds: int = 3, seconds: float = 8.0, bauds: Tuple[int, ...] = BAUDS) -> List[Target]:
    """The bench runner's entry: the bridge's target rows of issue 24."""
    return to_targets(measure(bauds, rounds, seconds))


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=8.0, help="flood length of one run")
    ap.add_argument("--slaves", type=int, default=3)
    ap.add_argument("--baud", type=int, action="append", help="paced baud rate (repeatable; default 115200 and 1M)")
    ap.add_argument("--profile", metavar="PREFIX", help="py-spy flame graphs of the bridge, PREFIX-<baud>-<round>.svg")
    ap.add_argument("--json", metavar="FILE", help="write the raw rounds here")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("fap_py").setLevel(logging.WARNING)   # open/close lines of every node
    results = measure(tuple(args.baud or BAUDS), args.rounds, args.seconds, args.slaves, args.profile)
    print("| baud | round | bus alone msg/s | bus -> bridge msg/s | bridge -> consumer msg/s | share "
          "| lost | dup | wire lost | bridge CPU | load avg |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for baud, rounds in results.items():
        for r in rounds:
            b = r["bridge"]
            print(f"| {_baud_name(baud)} | {r['round']} | {r['bus']['rate']:.0f} | {b['delivered_rate']:.0f} | "
                  f"{b['rate']:.0f} | {100 * r['share']:.1f} % | {b['lost']} | {b['duplicated']} | {b['wire_lost']} "
                  f"| {100 * b['bridge_cpu']:.0f} % | {b['load']:.1f} |")
    rows = to_targets(results)
    print()
    print(table(rows), end="")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({str(k): v for k, v in results.items()}, f, indent=1)
    return 0 if all(t.met for t in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
