"""``fap soak``: fault soak of FAP, exec async, mikroC and G485.

FAP and exec async run a master in this process and N slave *processes* on
the paced virtual bus with bit errors and byte drops; one slave is killed
(SIGKILL) and restarted, and the master's port is disconnected and comes
back. Every message carries its own sequence number and a SHA-256 digest,
so the report can say: sent / delivered intact / corrupted / duplicated /
lost, which counters account for the losses, how long recovery took, and
how RSS, threads and fds of every process moved.

mikroC and G485 guard their frames with an 8-bit check: they run on the
same bus with the same faults (at a higher bit error rate) and count how
many corrupted messages those checks let through, a rate to document, not
hide; a simulated bit-error channel fed to the decoders gives a second
figure.

The exit status is 1 when FAP or exec async delivered anything corrupted
or twice (or returned a stale reply), or mikroC delivered a frame twice;
docs/reliability.md has figures.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import random
import signal
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

log = logging.getLogger("fap_py.soak")

DIGEST = 32
_HDR = struct.Struct(">BBHI")      # src, dst, incarnation, seq


# -- messages -------------------------------------------------------------



class FaultPlan:
    """The faults every soak injects, on one schedule: slave 1 killed at a
    third of the run and restarted 2 s later, the master's port gone at two
    thirds for 1 s. Also measures recovery: the first good exchange with
    slave 1 after its restart and with anyone after the port came back."""

    def __init__(self, seconds: float, t0: float) -> None:
        self.t0 = t0
        self.kill_at, self.restart_at, self.disc_at = seconds / 3, seconds / 3 + 2.0, 2 * seconds / 3
        self.killed = self.restarted = self.disconnected = False
        self.restart_time: Optional[float] = None
        self.disc_end: Optional[float] = None
        self.rec_restart: Optional[float] = None
        self.rec_port: Optional[float] = None

    def step(self, children: Dict[str, Any], start_slave: Any, bus: Any,
             on_kill: Any = None) -> float:
        """Inject what is due now; return the run time in seconds."""
        now = time.monotonic() - self.t0
        if not self.killed and now >= self.kill_at:
            children["slave1"].send_signal(signal.SIGKILL)
            children["slave1"].wait()
            if on_kill is not None:
                on_kill()
            self.killed = True
        if self.killed and not self.restarted and now >= self.restart_at:
            start_slave(1)
            self.restart_time = time.monotonic() - self.t0
            self.restarted = True
        if not self.disconnected and now >= self.disc_at:
            bus.disconnect(0, 1.0)
            self.disc_end = time.monotonic() - self.t0 + 1.0
            self.disconnected = True
        return now

    def good_exchange(self, node: int, t: float) -> None:
        """Note a good exchange with ``node`` at run time ``t`` (recovery times)."""
        if node == 1 and self.restart_time is not None and self.rec_restart is None \
                and t >= self.restart_time:
            self.rec_restart = t - self.restart_time
        if self.disc_end is not None and self.rec_port is None and t >= self.disc_end:
            self.rec_port = t - self.disc_end


def running(a: argparse.Namespace, t0: float, seconds: Optional[float] = None) -> bool:
    """True while one protocol's soak goes on: its time (``seconds``, default
    ``--seconds``) is not up and no SIGINT/SIGTERM came (``a.stop``)."""
    stop = getattr(a, "stop", None)
    return (time.monotonic() - t0 < (a.seconds if seconds is None else seconds)
            and not (stop is not None and stop.is_set()))


def _watch(p: Any, i: int, children: Dict[str, Any], threads: List[Any], reader: Any,
           key: Any) -> threading.Event:
    """Register ``p`` as slave ``i``'s process and start the thread reading its
    reports (``reader(p, key, up)``); ``up`` is set when the child says it is up."""
    up = threading.Event()
    children[f"slave{i}"] = p
    t = threading.Thread(target=reader, args=(p, key, up), daemon=True)
    t.start()
    threads.append(t)
    return up

def _teardown(master: Any, sampler: Any, children: Dict[Any, Any], threads: List[Any],
              bus: Any) -> Any:
    """Stop the sampler, close the master, kill the slave processes, join the
    reader threads; return the bus counters (read before the bus closes)."""
    sampler.stop.set()
    sampler.join()
    master.close()
    for p in children.values():
        p.kill()
        p.wait()
    for th in threads:
        th.join(timeout=2)
    bstats = bus.stats()
    bus.close()
    return bstats

def make_message(src: int, dst: int, inc: int, seq: int, rnd: random.Random,
                 lo: int = 16, hi: int = 200) -> bytes:
    """Header (src, dst, incarnation, seq) + random payload + SHA-256 of both."""
    body = _HDR.pack(src, dst, inc & 0xFFFF, seq) + rnd.randbytes(rnd.randint(lo, hi))
    return body + hashlib.sha256(body).digest()


def check_message(data: bytes) -> Optional[Tuple[int, int, int, int]]:
    """(src, dst, inc, seq) of an intact message, None if it is corrupted."""
    if len(data) < _HDR.size + DIGEST:
        return None
    body, digest = data[:-DIGEST], data[-DIGEST:]
    if hashlib.sha256(body).digest() != digest:
        return None
    return _HDR.unpack_from(body)


# -- resources ------------------------------------------------------------

def proc_sample(pid: int) -> Optional[Dict[str, int]]:
    """RSS (KiB), threads and open fds of a process (Linux /proc)."""
    try:
        status = open(f"/proc/{pid}/status").read()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    vals = {}
    for line in status.splitlines():
        k, _, v = line.partition(":")
        if k in ("VmRSS", "Threads"):
            vals[k] = int(v.split()[0])
    return {"rss_kib": vals.get("VmRSS", 0), "threads": vals.get("Threads", 0), "fds": fds}


class Sampler(threading.Thread):
    """Samples this process and the live children every `period` seconds."""

    def __init__(self, period: float, children: "Dict[str, subprocess.Popen[bytes]]") -> None:
        super().__init__(daemon=True)
        self.period = period
        self.children = children
        self.samples: List[Dict[str, Any]] = []
        self.stop = threading.Event()
        self.t0 = time.monotonic()

    def run(self) -> None:
        while True:
            row: Dict[str, Any] = {"t": round(time.monotonic() - self.t0, 2),
                                   "master": proc_sample(os.getpid())}
            for name, p in list(self.children.items()):
                row[name] = proc_sample(p.pid)
            self.samples.append(row)
            if self.stop.wait(self.period):
                return

    def summary(self) -> Dict[str, Any]:
        out: Dict[str, Any] = {}
        series = [s["master"] for s in self.samples if s.get("master")]
        if series:
            for k in ("rss_kib", "threads", "fds"):
                vals = [s[k] for s in series]
                out[k] = {"first": vals[0], "last": vals[-1], "max": max(vals)}
        out["samples"] = len(self.samples)
        return out


# -- slave processes --------------------------------------------------------

def _child(kind: str, path: str, node: int, baud: int, seed: int, rate: float,
           until: float = 0.0) -> "subprocess.Popen[bytes]":
    """A slave process; a FAP one queues `rate` messages/s for `until` seconds."""
    import fap_py

    # run from the directory holding the fap_py this process uses, so the
    # child imports the same (built) package, not a source tree in the cwd
    home = os.path.dirname(os.path.dirname(os.path.abspath(fap_py.__file__)))
    return subprocess.Popen([sys.executable, "-m", "fap_py.commands.soak", "--child", kind, path,
                             str(node), str(baud), str(seed), str(rate), str(until)],
                            stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, cwd=home)


def _fap_slave_child(path: str, sid: int, baud: int, seed: int, rate: float, until: float) -> int:
    from fap_py.fap import Slave

    out_lock = threading.Lock()

    def say(*parts: Any) -> None:
        with out_lock:
            sys.stdout.write(" ".join(str(p) for p in parts) + "\n")
            sys.stdout.flush()

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
                say("T", json.dumps(s.stats().as_dict()))
                last = time.monotonic()


def _exec_slave_child(path: str, node: int, baud: int, seed: int, rate: float, until: float) -> int:
    from fap_py.execasync import Slave

    def handler(req: Any) -> Optional[bytes]:
        data = req.data
        if len(data) < 8 + DIGEST or hashlib.sha256(data[:-DIGEST]).digest() != data[-DIGEST:]:
            sys.stdout.write("X\n")
            sys.stdout.flush()
            return None
        mid = data[:8]
        sys.stdout.write(f"H {int.from_bytes(mid, 'big')} {req.seq}\n")
        sys.stdout.flush()
        return mid + hashlib.sha256(b"reply" + data).digest()

    with Slave(path, baud, node=node, handler=handler) as s:
        sys.stdout.write("U\n")
        sys.stdout.flush()
        while True:
            try:
                s.serve(timeout=0.5)
            except Exception:            # the bus went away: the soak is over
                return 0


# -- FAP ------------------------------------------------------------------------

@dataclass
class Incarnation:
    inc: int = -1
    sent: List[int] = field(default_factory=list)
    stats: Dict[str, int] = field(default_factory=dict)
    got: Dict[Tuple[int, int], int] = field(default_factory=dict)   # (inc, seq) from master
    bad: int = 0
    killed: bool = False


def _reader(p: "subprocess.Popen[bytes]", rec: Incarnation, up: threading.Event) -> None:
    assert p.stdout is not None
    for raw in p.stdout:
        parts = raw.decode(errors="replace").split(" ", 1)
        tag, rest = parts[0].strip(), (parts[1].strip() if len(parts) > 1 else "")
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


def soak_fap(a: argparse.Namespace) -> Dict[str, Any]:
    from fap_py.fap import Master
    from fap_py.vbus import VirtualBus

    n = a.slaves
    rnd = random.Random(a.seed)
    bus = VirtualBus(ports=n + 1, baud=a.baud, seed=a.seed)
    bus.set_fault(None, bit_error_rate=a.bit_error_rate, drop_rate=a.drop_rate)
    children: Dict[str, "subprocess.Popen[bytes]"] = {}
    incs: Dict[int, List[Incarnation]] = {i: [] for i in range(1, n + 1)}
    threads: List[threading.Thread] = []

    def start_slave(i: int) -> threading.Event:
        rec = Incarnation()
        p = _child("fap", bus.paths[i], i, a.baud, a.seed + i, a.slave_rate,
                   max(0.0, a.seconds - (time.monotonic() - t_start)))
        incs[i].append(rec)
        return _watch(p, i, children, threads, _reader, rec)

    sampler = Sampler(a.sample, children)
    sampler.start()
    t_start = time.monotonic()
    for i in range(1, n + 1):
        start_slave(i)
    # Windows generous for the virtual bus: a pty write returns before the
    # bytes' wire time (up to ~4 KiB wait in the relay), so a deadline
    # counted from the write is early by that backlog (docs/reliability.md).
    master = Master(bus.paths[0], a.baud, slaves=list(range(1, n + 1)), id_cycle=0.5,
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

    for fn in (receiver, watcher):
        t = threading.Thread(target=fn, daemon=True)
        t.start()
        threads.append(t)
    try:
        master.wait_active(timeout=10)
    except Exception as e:               # reported below as losses, not a crash
        log.warning("slaves not all active at the start: %s", e)
    # faults: kill slave 1 at 1/3 (back after 2 s), master port gone at 2/3 for 1 s
    plan = FaultPlan(a.seconds, t0)
    seq = 0
    while running(a, t0):
        plan.step(children, lambda i: start_slave(i).wait(10), bus,
                  on_kill=lambda: setattr(incs[1][-1], "killed", True))
        dst = 1 + seq % n
        msg = make_message(0, dst, 0, seq, rnd)
        try:
            master.send(msg, to=dst, timeout=0.5)
        except Exception:
            continue                     # queue full (bus down): try again
        sent[(dst, seq)] = 1
        seq += 1
        time.sleep(1.0 / a.master_rate)  # pacing of the load, not synchronisation
    try:
        master.flush(timeout=5)
    except Exception:
        pass
    # drain: the slaves stopped queueing at the end; wait (bounded) until
    # what the live ones queued has arrived or nothing moves any more
    last, still = -1, 0
    drain_start = time.monotonic()
    while running(a, drain_start, 10.0) and still < 10:
        with lock:
            now_got = sum(got.values())
        still = still + 1 if now_got == last else 0
        last = now_got
        time.sleep(0.1)                  # polling a counter with a deadline
    stop.set()
    mstats = master.stats().as_dict()
    bstats = _teardown(master, sampler, children, threads, bus)

    # master -> slaves
    delivered = dup = 0
    for i in range(1, n + 1):
        for rec in incs[i]:
            for (_src_inc, s), c in rec.got.items():
                if (i, s) in sent:
                    delivered += 1
                    dup += c - 1
    corrupted = sum(rec.bad for lst in incs.values() for rec in lst)
    m2s_lost = len(sent) - delivered
    slave_counts = {k: sum(rec.stats.get(k, 0) for lst in incs.values() for rec in lst)
                    for k in ("crc_errors", "framing_errors", "gap_timeouts", "rx_dropped", "garbage_bytes")}
    # slaves -> master
    s_sent = s_deliv = s_dup = lost_killed = 0
    for i in range(1, n + 1):
        for rec in incs[i]:
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
        "protocol": "fap", "seconds": a.seconds, "slaves": n, "baud": a.baud,
        "faults": {"bit_error_rate": a.bit_error_rate, "drop_rate": a.drop_rate,
                   "bus_bit_errors": bstats.bit_errors, "bus_dropped_bytes": bstats.dropped,
                   "bus_collisions": bstats.collisions, "slave_killed": 1, "port_disconnects": bstats.disconnects},
        "master_to_slaves": {"sent": len(sent), "delivered_intact": delivered, "corrupted": corrupted,
                             "duplicated": dup, "lost": m2s_lost, "loss_counters": counted_m2s},
        "slaves_to_master": {"sent": s_sent, "delivered_intact": s_deliv, "corrupted": corrupt_at_master,
                             "duplicated": s_dup, "lost": s_sent - s_deliv,
                             "lost_in_killed_process": lost_killed, "loss_counters": counted_s2m},
        "every_loss_counted": m2s_lost <= counted_m2s and (s_sent - s_deliv) <= counted_s2m,
        "recovery_s": {"slave_restart_to_active": round(rec_active[0], 3) if rec_active else None,
                       "port_back_to_reopened": round(reopened[0], 3) if reopened else None},
        "master_stats": mstats, "slave_loss_counters": slave_counts,
        "resources": sampler.summary(),
        "ok": corrupted == 0 and dup == 0 and corrupt_at_master == 0 and s_dup == 0,
    }


# -- exec async -----------------------------------------------------------------

def soak_exec(a: argparse.Namespace) -> Dict[str, Any]:
    from fap_py.errors import FapError
    from fap_py.execasync import Master
    from fap_py.vbus import VirtualBus

    n = a.slaves
    rnd = random.Random(a.seed)
    bus = VirtualBus(ports=n + 1, baud=a.baud, seed=a.seed + 1)
    bus.set_fault(None, bit_error_rate=a.bit_error_rate, drop_rate=a.drop_rate)
    children: Dict[str, "subprocess.Popen[bytes]"] = {}
    execs: Dict[int, Dict[int, List[int]]] = {i: {} for i in range(1, n + 1)}   # node -> id -> seqs
    bad_at_slave = [0]
    threads: List[threading.Thread] = []

    def reader(p: "subprocess.Popen[bytes]", node: int, up: threading.Event) -> None:
        assert p.stdout is not None
        for raw in p.stdout:
            f = raw.decode(errors="replace").split()
            if not f:
                continue
            if f[0] == "U":
                up.set()
            elif f[0] == "X":
                bad_at_slave[0] += 1
            elif f[0] == "H":
                execs[node].setdefault(int(f[1]), []).append(int(f[2]))

    def start_slave(i: int) -> None:
        p = _child("exec", bus.paths[i], i, a.baud, a.seed + i, 0)
        _watch(p, i, children, threads, reader, i).wait(10)

    sampler = Sampler(a.sample, children)
    sampler.start()
    for i in range(1, n + 1):
        start_slave(i)
    master = Master(bus.paths[0], a.baud, timeout=a.timeout, retries=a.retries)
    t0 = time.monotonic()
    mid = 0
    ok = corrupted = stale = failures = port_errors = 0
    sent_ids: Dict[int, int] = {}
    plan = FaultPlan(a.seconds, t0)
    while running(a, t0):
        plan.step(children, start_slave, bus)
        node = 1 + mid % n
        body = mid.to_bytes(8, "big") + rnd.randbytes(rnd.randint(8, 180))
        req = body + hashlib.sha256(body).digest()
        sent_ids[mid] = node
        try:
            reply = master.transact(node, req)
        except FapError as e:
            if type(e).__name__ in ("PortError",) or "port" in type(e).__name__.lower():
                port_errors += 1
                try:
                    master.reopen()
                except FapError:
                    time.sleep(0.05)     # the device is still gone: pace the reopen attempts
            else:
                failures += 1
            mid += 1
            continue
        t = time.monotonic() - t0
        if reply[:8] != req[:8]:
            stale += 1
        elif reply[8:] != hashlib.sha256(b"reply" + req).digest():
            corrupted += 1
        else:
            ok += 1
            plan.good_exchange(node, t)
        mid += 1
    time.sleep(0.3)
    st = master.stats
    mstats = {k: int(getattr(st, k)) for k in st.__dataclass_fields__}
    bstats = _teardown(master, sampler, children, threads, bus)
    dup = dup_seq0 = 0
    for ids in execs.values():
        for seqs in ids.values():
            if len(seqs) > 1:
                if all(s == 0 for s in seqs):
                    dup_seq0 += len(seqs) - 1     # the documented SeqNo-0 retry cost
                else:
                    dup += len(seqs) - 1
    return {
        "protocol": "exec", "seconds": a.seconds, "slaves": n, "baud": a.baud,
        "faults": {"bit_error_rate": a.bit_error_rate, "drop_rate": a.drop_rate,
                   "bus_bit_errors": bstats.bit_errors, "bus_dropped_bytes": bstats.dropped,
                   "bus_collisions": bstats.collisions, "slave_killed": 1, "port_disconnects": bstats.disconnects},
        "transactions": mid, "replies_intact": ok, "replies_corrupted": corrupted,
        "stale_replies": stale, "failed": failures, "port_errors": port_errors,
        "handler_runs": sum(len(s) for ids in execs.values() for s in ids.values()),
        "duplicated": dup, "duplicated_seq0_documented": dup_seq0,
        "corrupt_requests_reaching_handler": bad_at_slave[0],
        # every transaction that got no intact reply is in the master's failures
        "every_loss_counted": mid - ok - corrupted - stale == mstats["failures"],
        "recovery_s": {"slave_restart_to_reply": round(plan.rec_restart, 3) if plan.rec_restart is not None else None,
                       "port_back_to_reply": round(plan.rec_port, 3) if plan.rec_port is not None else None},
        "master_stats": mstats, "resources": sampler.summary(),
        "ok": corrupted == 0 and stale == 0 and dup == 0 and bad_at_slave[0] == 0,
    }


# -- mikroC and G485: what an 8-bit check lets through --------------------------------

def _channel(rnd: random.Random, frame: bytes, ber: float) -> bytes:
    out = bytearray(frame)
    for i in range(len(out)):
        for bit in range(8):
            if rnd.random() < ber:
                out[i] ^= 1 << bit
    return bytes(out)


def soak_check8(a: argparse.Namespace, proto: str) -> Dict[str, Any]:
    rnd = random.Random(a.seed)
    ber = a.check8_ber
    sent = intact = detected = undetected = damaged = lost = 0
    t0 = time.monotonic()
    if proto == "mikroc":
        from fap_py import mikroc
        while running(a, t0, a.check8_seconds):
            addr, data, fm = rnd.randrange(256), rnd.randbytes(rnd.randint(0, 3)), rnd.random() < 0.5
            frame = mikroc.encode(addr, data, from_master=fm)
            wire = _channel(rnd, frame, ber)
            sent += 1
            damaged += wire != frame
            evs = mikroc.Decoder().feed(wire)
            msgs = [e for e in evs if isinstance(e, mikroc.Message)]
            if not msgs:
                detected += wire != frame
                lost += wire == frame
            elif msgs[0].address == addr and msgs[0].data == data and msgs[0].from_master == fm and len(msgs) == 1:
                intact += 1
            else:
                undetected += 1
    else:
        from fap_py.g485 import codec
        while running(a, t0, a.check8_seconds):
            data = rnd.randbytes(rnd.randint(1, 12))
            frame = codec.encode_write(rnd.randint(1, 126), rnd.randint(1, 100 - len(data) + 1), data)
            wire = _channel(rnd, frame, ber)
            sent += 1
            damaged += wire != frame
            p = codec.Parser()
            pk = [e for e in p.feed(wire) + p.expire() if isinstance(e, codec.Packet)]
            if not pk:
                detected += wire != frame
                lost += wire == frame
            elif len(pk) == 1 and pk[0].raw == frame:
                intact += 1
            else:
                undetected += 1
    return {"protocol": proto, "bit_error_rate": ber, "frames": sent, "damaged_on_wire": damaged,
            "delivered_intact": intact, "damage_detected": detected,
            "damage_undetected": undetected, "clean_but_lost": lost,
            "undetected_per_damaged_frame": round(undetected / damaged, 5) if damaged else 0.0}


# -- command ------------------------------------------------------------------------

def register(sub: argparse._SubParsersAction) -> None:
    from ._options import add_command, add_link_options, add_output_options, baud, count, seconds

    p = add_command(
        sub, "soak", help="fault soak: master + slave processes on the paced virtual bus",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
        example="fap soak --seconds 30 --slaves 4 --json")
    p.add_argument("--protocol", choices=["fap", "exec", "mikroc", "g485", "all"], default="all",
                   help="what to soak")
    p.add_argument("--seconds", metavar="S", type=seconds, default=30.0,
                   help="duration of each protocol's bus soak")
    p.add_argument("--slaves", metavar="N", type=count, default=3, help="slave processes (1..31)")
    p.add_argument("--baud", metavar="N", type=baud, default=115200, help="paced bus rate, bit/s")
    p.add_argument("--bit-error-rate", metavar="P", type=seconds, default=2e-5,
                   help="per byte, every port")
    p.add_argument("--drop-rate", metavar="P", type=seconds, default=2e-5, help="per byte, every port")
    p.add_argument("--bus8-bit-error-rate", metavar="P", type=seconds, default=0.005,
                   help="mikroC / G485 bus soak: bit error rate per byte (higher than "
                        "--bit-error-rate, so that enough frames are damaged to measure what "
                        "the 8-bit checks let through)")
    link = add_link_options(p, timeout_default=0.1, retries_default=3)
    link.description = "exec async, mikroC and G485 master"
    p.add_argument("--master-rate", metavar="R", type=seconds, default=25.0,
                   help="FAP messages/s the master queues")
    p.add_argument("--slave-rate", metavar="R", type=seconds, default=10.0,
                   help="FAP messages/s each slave queues")
    p.add_argument("--check8-seconds", metavar="S", type=seconds, default=5.0,
                   help="mikroC / G485 channel run time")
    p.add_argument("--check8-ber", metavar="P", type=seconds, default=0.01,
                   help="mikroC / G485 channel bit error rate")
    p.add_argument("--sample", metavar="S", type=seconds, default=1.0,
                   help="resource sampling period, seconds")
    p.add_argument("--seed", metavar="N", type=count, default=12,
                   help="seed of every random choice and fault")
    add_output_options(p)
    p.set_defaults(func=run)


def _human(res: Dict[str, Any]) -> str:
    lines = [f"== {res['protocol']}"]
    lines += [f"  {k}: {v}" for k, v in res.items() if k not in ("protocol", "master_stats")]
    return "\n".join(lines)


def run(a: argparse.Namespace) -> int:
    """The command: one result per protocol (JSON line or text); exit 1 if FAP or exec
    async delivered anything corrupted or twice, or mikroC delivered a frame twice
    (mikroC / G485 corruption is measured, not failed on). Errors reach ``run_command``."""
    from ._node import stop_on_sigterm, timed_progress
    from ._options import EXIT_INTERRUPTED, UsageError, emit

    if not 1 <= a.slaves <= 31 or a.seconds <= 0 or a.sample <= 0:
        raise UsageError(f"need --slaves 1..31, --seconds > 0, --sample > 0 (not {a.slaves}, "
                         f"{a.seconds}, {a.sample})")
    if not (a.bit_error_rate <= 1 and a.drop_rate <= 1 and a.check8_ber <= 1 and a.bus8_bit_error_rate <= 1):
        raise UsageError("--bit-error-rate, --drop-rate, --bus8-bit-error-rate and --check8-ber "
                         "are probabilities (0..1)")
    protos = ["fap", "exec", "mikroc", "g485"] if a.protocol == "all" else [a.protocol]
    failed = False
    with stop_on_sigterm() as stop:
        a.stop = stop         # the soak loops end early when it is set (running())
        for proto in protos:
            total = a.seconds + (a.check8_seconds if proto in ("mikroc", "g485") else 0)
            with timed_progress(f"soak {proto}", total):
                res = _soak_one(a, proto)
            if stop.is_set():
                res["interrupted"] = True
            emit(a, res, _human(res))
            failed |= not res.get("ok", True)
            if stop.is_set():
                break
    if stop.is_set():     # Ctrl-C / SIGTERM: the results so far, then exit 130
        return EXIT_INTERRUPTED
    return 1 if failed else 0


def _soak_one(a: argparse.Namespace, proto: str) -> Dict[str, Any]:
    if proto == "fap":
        return soak_fap(a)
    if proto == "exec":
        return soak_exec(a)
    from . import _soak8bit
    res = (_soak8bit.soak_mikroc if proto == "mikroc" else _soak8bit.soak_g485)(a)
    # the 8-bit check alone on a simulated channel: a second figure
    res["channel"] = soak_check8(a, proto)
    return res


def _die_with_parent() -> None:
    """A slave process must not outlive an interrupted soak (Linux prctl)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


if __name__ == "__main__" and len(sys.argv) > 2 and sys.argv[1] == "--child":
    _die_with_parent()
    _kind, _path, _node, _baud, _seed, _rate, _until = sys.argv[2:9]
    try:
        if _kind in ("mikroc", "g485"):
            from fap_py.commands import _soak8bit
            if _kind == "mikroc":
                sys.exit(_soak8bit.mikroc_slave_child(_path, int(_node), int(_baud)))
            sys.exit(_soak8bit.g485_sim_child(_path, int(_node), int(_baud), int(_seed)))
        fn = _fap_slave_child if _kind == "fap" else _exec_slave_child
        sys.exit(fn(_path, int(_node), int(_baud), int(_seed), float(_rate), float(_until)))
    except (KeyboardInterrupt, BrokenPipeError):
        sys.exit(0)
