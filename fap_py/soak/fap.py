"""FAP soak: the master queues messages to every slave while each slave process queues messages
to the master; every message carries its sender, incarnation, sequence number and a SHA-256
digest, so the report says sent / delivered intact / corrupted / duplicated / lost in both
directions, and which counters account for the losses. Fails (``ok`` false) on any corrupted
or duplicated delivery."""
from __future__ import annotations

import json
import os
import random
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

from .harness import Config, FaultPlan, Rig, check_message, log, make_message, reports, running, say

NAME = "fap"
_LOSS_KEYS = ("crc_errors", "framing_errors", "gap_timeouts", "rx_dropped", "garbage_bytes")


def child(path: str, sid: int, baud: int, seed: int, rate: float, until: float) -> int:
    """A FAP slave process: queues ``rate`` messages/s to the master for ``until`` seconds,
    reports each one sent (``S``), each one received (``R``) and its counters (``T``)."""
    from fap_py.fap import Slave

    inc = os.getpid() & 0xFFFF
    rnd = random.Random(seed ^ os.getpid())
    stop = threading.Event()
    end = time.monotonic() + until
    # a turn shorter than the master's DATA_DONE limit: a slave still
    # sending when the master gives up on it would collide with the master
    with Slave(path, baud, id=sid, send_budget=0.1) as s:
        say("U", inc)

        def sender() -> None:
            seq = 0
            while not stop.is_set() and time.monotonic() < end:
                msg = make_message(sid, 0, inc, seq, rnd)
                try:
                    s.send(msg, to=0, timeout=1.0)
                except Exception:           # queue full for 1 s: try the next one
                    continue
                say("S", inc, seq)
                seq += 1
                stop.wait(1.0 / rate)

        t = threading.Thread(target=sender, daemon=True)
        t.start()
        last = time.monotonic()
        while True:
            try:
                m = s.recv(timeout=0.2)
                hdr = check_message(m.data)
                if hdr is None:
                    say("R", m.source, "BAD")
                else:
                    say("R", m.source, hdr[2], hdr[3])
            except Exception:
                pass
            if time.monotonic() - last >= 0.25:
                say("T", json.dumps(s.stats.as_dict()))
                last = time.monotonic()


@dataclass
class Incarnation:
    """What one slave process reported (a restarted slave is a new incarnation)."""

    inc: int = -1
    sent: List[int] = field(default_factory=list)
    stats: Dict[str, int] = field(default_factory=dict)
    got: Dict[Tuple[int, int], int] = field(default_factory=dict)   # (inc, seq) from master
    bad: int = 0
    killed: bool = False


def _reader(p: Any, rec: Incarnation, up: threading.Event) -> None:
    for tag, rest in reports(p):
        if tag == "U":
            rec.inc = int(rest)
            up.set()
        elif tag == "S":
            rec.sent.append(int(rest.split()[1]))
        elif tag == "T":
            rec.stats = json.loads(rest)
        elif tag == "R":
            f = rest.split()
            if f[1] == "BAD":
                rec.bad += 1
            else:
                key = (int(f[1]), int(f[2]))
                rec.got[key] = rec.got.get(key, 0) + 1


def run(cfg: Config) -> Dict[str, Any]:
    """The FAP bus soak and its report."""
    from fap_py.fap import Master

    n = cfg.slaves
    rnd = random.Random(cfg.seed)
    rig = Rig(NAME, cfg, seed=cfg.seed, bit_error_rate=cfg.bit_error_rate)
    incs: Dict[int, List[Incarnation]] = {i: [] for i in rig.nodes}

    def start_slave(i: int) -> threading.Event:
        rec = Incarnation()
        incs[i].append(rec)
        return rig.spawn(i, _reader, rec, cfg.slave_rate,
                         max(0.0, cfg.seconds - (time.monotonic() - t_start)))

    t_start = time.monotonic()
    for i in rig.nodes:
        start_slave(i)
    # Windows generous for the virtual bus: a pty write returns before the
    # bytes' wire time (up to ~4 KiB wait in the relay), so a deadline
    # counted from the write is early by that backlog (docs/reliability.md).
    master = Master(rig.bus.paths[0], cfg.baud, slaves=list(rig.nodes), id_cycle=0.5,
                    id_answer_timeout=0.5, data_done_timeout=1.0, reopen_interval=0.05,
                    event_queue=4096)
    t0 = time.monotonic()
    sent: Dict[Tuple[int, int], int] = {}          # (dst, seq) -> 1
    got: Dict[Tuple[int, int, int], int] = {}      # (src, inc, seq) -> count
    corrupt_at_master = 0
    events: List[Tuple[float, str, int]] = []
    stop = threading.Event()
    lock = threading.Lock()

    def receiver() -> None:
        nonlocal corrupt_at_master
        while not stop.is_set():
            try:
                m = master.recv(timeout=0.1)
            except Exception:
                continue
            hdr = check_message(m.data)
            with lock:
                if hdr is None or hdr[0] != m.source:
                    corrupt_at_master += 1
                else:
                    key = (hdr[0], hdr[2], hdr[3])
                    got[key] = got.get(key, 0) + 1

    def watcher() -> None:
        while not stop.is_set():
            try:
                ev = master.wait_event(timeout=0.1)
            except Exception:
                continue
            events.append((time.monotonic() - t0, ev.kind.name, ev.id))

    rig.thread(receiver)
    rig.thread(watcher)
    try:
        master.wait_active(timeout=10)
    except Exception as e:               # reported below as losses, not a crash
        log.warning("slaves not all active at the start: %s", e)
    plan = FaultPlan(cfg.seconds, t0)
    seq = 0
    while running(cfg, t0):
        plan.step(rig.children, lambda i: start_slave(i).wait(10), rig.bus,
                  on_kill=lambda: setattr(incs[1][-1], "killed", True))
        dst = 1 + seq % n
        msg = make_message(0, dst, 0, seq, rnd)
        try:
            master.send(msg, to=dst, timeout=0.5)
        except Exception:
            continue                     # queue full (bus down): try again
        sent[(dst, seq)] = 1
        seq += 1
        time.sleep(1.0 / cfg.master_rate)  # pacing of the load, not synchronisation
    try:
        master.flush(timeout=5)
    except Exception:
        pass
    # drain: the slaves stopped queueing at the end; wait (bounded) until
    # what the live ones queued has arrived or nothing moves any more
    last, still = -1, 0
    drain_start = time.monotonic()
    while running(cfg, drain_start, 10.0) and still < 10:
        with lock:
            now_got = sum(got.values())
        still = still + 1 if now_got == last else 0
        last = now_got
        time.sleep(0.1)                  # polling a counter with a deadline
    stop.set()
    mstats = master.stats.as_dict()
    bstats = rig.close(master)
    return _report(rig, bstats, incs, sent, got, corrupt_at_master, events, plan, mstats)


def _report(rig: Rig, bstats: Any, incs: Dict[int, List[Incarnation]], sent: Dict[Tuple[int, int], int],
            got: Dict[Tuple[int, int, int], int], corrupt_at_master: int,
            events: List[Tuple[float, str, int]], plan: FaultPlan, mstats: Dict[str, int]) -> Dict[str, Any]:
    # master -> slaves
    delivered = dup = 0
    for i, lst in incs.items():
        for rec in lst:
            for (_src_inc, s), c in rec.got.items():
                if (i, s) in sent:
                    delivered += 1
                    dup += c - 1
    corrupted = sum(rec.bad for lst in incs.values() for rec in lst)
    m2s_lost = len(sent) - delivered
    slave_counts = {k: sum(rec.stats.get(k, 0) for lst in incs.values() for rec in lst) for k in _LOSS_KEYS}
    # slaves -> master
    s_sent = s_deliv = s_dup = lost_killed = 0
    for i, lst in incs.items():
        for rec in lst:
            for s in rec.sent:
                c = got.get((i, rec.inc, s), 0)
                s_sent += 1
                if c:
                    s_deliv += 1
                    s_dup += c - 1
                elif rec.killed:
                    lost_killed += 1

    def ev_of(kind: str, sid: Optional[int] = None) -> List[float]:
        return [t for t, k, i in events if k == kind and (sid is None or i == sid)]

    restart_time, disc_end = plan.restart_time, plan.disc_end
    rec_active = [t - restart_time for t in ev_of("SLAVE_ACTIVE", 1) if restart_time and t >= restart_time]
    reopened = [t - disc_end for t in ev_of("PORT_REOPENED") if disc_end and t >= disc_end - 1.0]
    counted_m2s = mstats["tx_unconfirmed"] + mstats["tx_to_inactive"] + \
        slave_counts["crc_errors"] + slave_counts["framing_errors"] + slave_counts["gap_timeouts"] + \
        slave_counts["rx_dropped"] + mstats["write_errors"]
    counted_s2m = mstats["crc_errors"] + mstats["framing_errors"] + mstats["gap_timeouts"] + \
        mstats["rx_dropped"] + lost_killed
    return {
        **rig.report(bstats),
        "master_to_slaves": {"sent": len(sent), "delivered_intact": delivered, "corrupted": corrupted,
                             "duplicated": dup, "lost": m2s_lost, "loss_counters": counted_m2s},
        "slaves_to_master": {"sent": s_sent, "delivered_intact": s_deliv, "corrupted": corrupt_at_master,
                             "duplicated": s_dup, "lost": s_sent - s_deliv,
                             "lost_in_killed_process": lost_killed, "loss_counters": counted_s2m},
        "every_loss_counted": m2s_lost <= counted_m2s and (s_sent - s_deliv) <= counted_s2m,
        "recovery_s": {"slave_restart_to_active": round(rec_active[0], 3) if rec_active else None,
                       "port_back_to_reopened": round(reopened[0], 3) if reopened else None},
        "master_stats": mstats, "slave_loss_counters": slave_counts,
        "resources": rig.sampler.summary(),
        "ok": corrupted == 0 and dup == 0 and corrupt_at_master == 0 and s_dup == 0,
    }


def report(r: Dict[str, Any]) -> List[str]:
    """The summary lines of a report of :func:`run` (``.ci/soak.sh`` prints them)."""
    a, b = r["master_to_slaves"], r["slaves_to_master"]
    return [f"soak fap: m->s sent {a['sent']} intact {a['delivered_intact']} corrupted {a['corrupted']} "
            f"duplicated {a['duplicated']} lost {a['lost']} (counters {a['loss_counters']}); "
            f"s->m sent {b['sent']} intact {b['delivered_intact']} corrupted {b['corrupted']} "
            f"duplicated {b['duplicated']} lost {b['lost']}; recovery {r['recovery_s']}"]
