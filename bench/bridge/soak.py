#!/usr/bin/env python3
"""Soak and bench of ``fap bridge`` against a real mosquitto (docs/bridge.md).

One run = a private mosquitto on a free loopback port, a virtual bus with a
FAP master (the bridge, started as ``fap bridge --config ...`` in its own
process) and FAP slaves (this process), a consumer and a tx producer on the
broker.

* Bus -> broker: every slave sends numbered messages (slave, counter, send
  time) at ``--rate`` per second; the consumer (a persistent QoS 1 session)
  counts what arrives on ``<prefix>/<bus>/<node>/rx``.
* Broker -> bus: the producer publishes numbered tx (each with its own id)
  at ``--tx-rate``; after every reconnect it publishes the last 20 tx
  *again* with the same ids (a forced redelivery); the slaves count what
  they execute.
* Every ``--restart-every`` seconds the broker is stopped for
  ``--down`` seconds and started again (its persistence keeps sessions).

At the end it prints sent / received / lost / duplicated for both
directions and the bus -> consumer latency percentiles, and exits 1 if
anything was lost or duplicated. Bus -> broker: "duplicated" is a bus
message published twice by the bridge (two different ``seq``); the same
publication delivered again by MQTT (QoS 1 is at-least-once: a PUBACK lost
in a broker restart) carries the same ``seq`` and is counted apart as
"redelivered" -- a consumer drops it by ``(host, seq)`` (docs/bridge.md).

    python3 bench/bridge/soak.py --duration 660                 # the soak (11 min, restarts)
    python3 bench/bridge/soak.py --bench --duration 20          # throughput + latency, no restarts

Needs paho-mqtt (``pip install 'fap_py[bridge]'``) and mosquitto.

``--bench`` rates count from the first to the last arrival, so a stall of the bus
itself (a frame lost on a loaded paced bus waits for FAP's recovery timers) counts
against the bridge: the bridge's throughput target is measured by
``python -m bench.bridge.throughput`` (README.md), which compares the bridge with what
the bus delivered in the same window.
"""
from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import threading
import time
from typing import Dict, List

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))   # the checkout, for ``bench``

import paho.mqtt.client as mqtt  # noqa: E402

from bench import use_installed_fap_py  # noqa: E402
from bench.servers import Mosquitto  # noqa: E402

use_installed_fap_py()

from fap_py.fap import Slave  # noqa: E402
from fap_py.vbus import VirtualBus  # noqa: E402

MSG = struct.Struct("<BIQ")   # slave id, counter, send time (time.time_ns)


def pct(values: List[float], p: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(p / 100.0 * len(s)))]


class Consumer:
    """A persistent-session subscriber to the rx topics."""

    def __init__(self, port: int, prefix: str) -> None:
        self.lock = threading.Lock()
        self.seen: Dict[tuple, set] = {}     # bus message (slave, counter) -> bridge seqs it came with
        self.seqs: set = set()
        self.raw = 0
        self.redelivered = 0                 # a publication seen again (same seq): QoS 1 at-least-once
        self.dup_flag = 0                    # ... of which the broker marked DUP
        self.latency_ms: List[float] = []
        self.record_latency = True
        self.t_first = self.t_last = 0.0     # arrival times of the first and last new message
        self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="soak-consumer", clean_session=False)
        self.c.reconnect_delay_set(0.1, 1)
        self.c.on_connect = lambda c, u, f, rc, p: c.subscribe(f"{prefix}/+/+/rx", 1)
        self.c.on_message = self.on_message
        self.c.connect("127.0.0.1", port)
        self.c.loop_start()

    def on_message(self, c: mqtt.Client, u: object, m: mqtt.MQTTMessage) -> None:
        now = time.time_ns()
        doc = json.loads(m.payload)
        sid, n, t = MSG.unpack(bytes.fromhex(doc["data"]))
        with self.lock:
            self.raw += 1
            key = (sid, n)
            if doc["seq"] in self.seqs:
                self.redelivered += 1
                self.dup_flag += bool(m.dup)
                return
            self.seqs.add(doc["seq"])
            self.t_last = time.monotonic()
            self.t_first = self.t_first or self.t_last
            self.seen.setdefault(key, set()).add(doc["seq"])
            if self.record_latency:
                self.latency_ms.append((now - t) / 1e6)

    def unique(self) -> int:
        with self.lock:
            return len(self.seen)


class TxProducer:
    """Publishes numbered tx (QoS 1) and, after each reconnect, the last 20 again."""

    def __init__(self, port: int, prefix: str, bus: str, slaves: List[int]) -> None:
        self.prefix, self.bus, self.slaves = prefix, bus, slaves
        self.sent = 0
        self.replayed = 0
        self.history: List[tuple] = []
        self.lock = threading.Lock()
        self.connects = 0
        self.c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="soak-producer", clean_session=False)
        self.c.reconnect_delay_set(0.1, 1)
        self.c.max_queued_messages_set(0)
        self.c.on_connect = self.on_connect
        self.c.connect("127.0.0.1", port)
        self.c.loop_start()

    def on_connect(self, c: mqtt.Client, u: object, f: object, rc: object, p: object) -> None:
        self.connects += 1
        if self.connects > 1:    # a forced redelivery of the last 20 tx, same ids
            with self.lock:
                again = list(self.history[-20:])
            for topic, payload in again:
                c.publish(topic, payload, qos=1)
                self.replayed += 1

    def send(self) -> None:
        n = self.sent
        sid = self.slaves[n % len(self.slaves)]
        topic = f"{self.prefix}/{self.bus}/{sid}/tx"
        payload = json.dumps({"id": f"tx-{n}", "data": MSG.pack(sid, n, time.time_ns()).hex()})
        with self.lock:
            self.history.append((topic, payload))
            del self.history[:-20]
        self.c.publish(topic, payload, qos=1)   # queued by paho while the broker is down
        self.sent += 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--duration", type=float, default=660, help="seconds of traffic")
    ap.add_argument("--rate", type=float, default=50, help="messages/s per slave (bus -> broker)")
    ap.add_argument("--tx-rate", type=float, default=20, help="tx/s (broker -> bus)")
    ap.add_argument("--slaves", type=int, default=3)
    ap.add_argument("--bus-baud", type=int, default=0,
                    help="pace the virtual bus at this baud rate (0: as fast as the ptys go)")
    ap.add_argument("--restart-every", type=float, default=60, help="seconds between broker restarts")
    ap.add_argument("--down", type=float, default=5, help="seconds the broker stays down")
    ap.add_argument("--settle", type=float, default=120, help="longest wait for stragglers at the end")
    ap.add_argument("--bench", action="store_true",
                    help="no restarts: a flood phase (messages/s) then a paced phase (latency)")
    ap.add_argument("--flood-seconds", type=float, default=None,
                    help="--bench: length of the flood phase (default --duration; 0 skips it)")
    ap.add_argument("--json", action="store_true", help="also print the result as one JSON line")
    args = ap.parse_args()

    work = tempfile.mkdtemp(prefix="fap-bridge-soak-")
    prefix, busname = "soak", "line1"
    slave_ids = list(range(1, args.slaves + 1))
    broker = Mosquitto(os.path.join(work, "broker")).start()
    vbus = VirtualBus(args.slaves + 1, baud=args.bus_baud or None)
    conf = os.path.join(work, "bridge.toml")
    with open(conf, "w") as f:
        f.write(f"""[bridge]
host = "soak"
topic_prefix = "{prefix}"
state_dir = "state"
stats_interval = 5

[broker]
url = "mqtt://127.0.0.1:{broker.port}"
reconnect_min = 0.2
reconnect_max = 2

[[bus]]
name = "{busname}"
port = "{vbus.paths[0]}"
protocol = "fap"
role = "master"
slaves = {slave_ids}
id_cycle = 0.2
""")
    log = open(os.path.join(work, "bridge.log"), "w")
    bridge = subprocess.Popen([sys.executable, "-m", "fap_py", "-v", "bridge", "--config", conf,
                               "--drain", "30"], stderr=log, stdout=log, cwd=work)
    consumer = Consumer(broker.port, prefix)
    producer = TxProducer(broker.port, prefix, busname, slave_ids)
    slaves = [Slave(vbus.paths[i + 1], id=sid) for i, sid in enumerate(slave_ids)]
    executed: Dict[int, int] = {}
    ex_lock = threading.Lock()
    stop = threading.Event()
    sent = [0] * len(slaves)

    def slave_rx(s: Slave) -> None:
        for msg in s:
            _, n, _ = MSG.unpack(msg.data)
            with ex_lock:
                executed[n] = executed.get(n, 0) + 1

    def slave_tx(i: int, s: Slave, rate: float, until: float) -> None:
        period = 1.0 / rate if rate > 0 else 0.0
        nxt = time.monotonic()
        while not stop.is_set() and time.monotonic() < until:
            s.send(MSG.pack(s.id, sent[i], time.time_ns()), timeout=None)
            sent[i] += 1
            if period:
                nxt += period
                delay = nxt - time.monotonic()
                if delay > 0:
                    time.sleep(delay)   # load pacing, not synchronisation

    rx_threads = [threading.Thread(target=slave_rx, args=(s,), daemon=True) for s in slaves]
    for t in rx_threads:
        t.start()
    t0 = time.monotonic()
    # wait until the bridge is on the broker (its retained status says online)
    online = threading.Event()
    watcher = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="soak-watch")
    watcher.on_message = lambda c, u, m: online.set() if m.payload == b"online" else None
    watcher.on_connect = lambda c, u, f, rc, p: c.subscribe(f"{prefix}/bridge/soak/status", 1)
    watcher.connect("127.0.0.1", broker.port)
    watcher.loop_start()
    if not online.wait(30):
        print("bridge never came online; see", log.name)
        return 2
    watcher.loop_stop()
    watcher.disconnect()

    result: Dict[str, object] = {}
    restarts = 0
    if args.bench:
        # flood: every slave sends as fast as its queue allows
        consumer.record_latency = False
        flood = args.duration if args.flood_seconds is None else args.flood_seconds
        until = time.monotonic() + flood
        ths = [threading.Thread(target=slave_tx, args=(i, s, 0, until)) for i, s in enumerate(slaves)]
        for t in ths:
            t.start()
        for t in ths:
            t.join()
        total = sum(sent)
        deadline = time.monotonic() + args.settle
        while consumer.unique() < total and time.monotonic() < deadline:
            time.sleep(0.05)
        with consumer.lock:
            got, active = len(consumer.seen), consumer.t_last - consumer.t_first
        result["flood_sent"] = total
        result["flood_received"] = got
        result["flood_not_received"] = total - got
        result["flood_msgs_per_s"] = round(got / active, 1) if active > 0 else 0.0
        # paced: latency at a rate the bridge keeps up with
        consumer.record_latency = True
        base = sum(sent)
        until = time.monotonic() + args.duration
        ths = [threading.Thread(target=slave_tx, args=(i, s, args.rate, until)) for i, s in enumerate(slaves)]
        for t in ths:
            t.start()
        for t in ths:
            t.join()
        result["paced_rate_per_s"] = args.rate * len(slaves)
        result["paced_sent"] = sum(sent) - base
    else:
        until = t0 + args.duration
        ths = [threading.Thread(target=slave_tx, args=(i, s, args.rate, until), daemon=True)
               for i, s in enumerate(slaves)]
        for t in ths:
            t.start()
        next_restart = time.monotonic() + args.restart_every
        tx_period = 1.0 / args.tx_rate
        next_tx = time.monotonic()
        while time.monotonic() < until:
            now = time.monotonic()
            if now >= next_restart:
                broker.stop()
                down_until = now + args.down
                while time.monotonic() < down_until:     # traffic keeps flowing into the queues
                    if time.monotonic() >= next_tx:
                        producer.send()
                        next_tx += tx_period
                    time.sleep(0.01)
                broker.start()
                restarts += 1
                print(f"[{time.monotonic() - t0:6.0f} s] broker restart {restarts}: sent {sum(sent)}, "
                      f"received {consumer.unique()}, tx sent {producer.sent}, executed {len(executed)}",
                      flush=True)
                next_restart = time.monotonic() + args.restart_every
            if time.monotonic() >= next_tx:
                producer.send()
                next_tx += tx_period
            time.sleep(0.005)
        for t in ths:
            t.join()

    # settle: wait until everything arrived (or --settle passes)
    total = sum(sent)
    deadline = time.monotonic() + args.settle
    while time.monotonic() < deadline:
        with ex_lock:
            tx_done = len(executed) >= producer.sent
        if consumer.unique() >= total and tx_done:
            break
        time.sleep(0.1)
    with consumer.lock, ex_lock:
        dup_rx = sum(len(c) - 1 for c in consumer.seen.values())
        dup_tx = sum(c - 1 for c in executed.values())
        result.update({
            "duration_s": round(time.monotonic() - t0, 1), "broker_restarts": restarts,
            "rx_sent": total, "rx_received_unique": len(consumer.seen), "rx_received_raw": consumer.raw,
            "rx_lost": total - len(consumer.seen), "rx_duplicated": dup_rx,
            "rx_redelivered_same_seq": consumer.redelivered, "rx_redelivered_dup_flag": consumer.dup_flag,
            "tx_sent": producer.sent, "tx_replayed_on_purpose": producer.replayed,
            "tx_executed_unique": len(executed), "tx_lost": producer.sent - len(executed),
            "tx_duplicated": dup_tx,
            "latency_ms_p50": round(pct(consumer.latency_ms, 50), 2),
            "latency_ms_p99": round(pct(consumer.latency_ms, 99), 2),
        })
    stop.set()
    bridge.terminate()
    try:
        bridge.wait(40)
    except subprocess.TimeoutExpired:
        bridge.kill()
    for s in slaves:
        s.close()
    consumer.c.loop_stop()
    producer.c.loop_stop()
    broker.stop()
    vbus.close()
    for k, v in result.items():
        print(f"{k:24} {v}")
    print(f"bridge exit code {bridge.returncode}; work dir {work}")
    if args.json:
        print(json.dumps(result))
    bad = result["rx_duplicated"] or result["tx_lost"] or result["tx_duplicated"]
    if not args.bench:     # a flood may overrun the engine's receive queue on purpose
        bad = bad or result["rx_lost"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
