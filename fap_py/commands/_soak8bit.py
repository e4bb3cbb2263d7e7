"""Bus soaks of the two protocols with an 8-bit check: mikroC and G485.

Same bus and faults as the FAP / exec async soaks (``fap soak``): a master
in this process, N slave processes on the paced virtual bus with bit errors
and byte drops, slave 1 killed and restarted, the master's port
disconnected and back. Both checks are 8 bits wide, so some corrupted
frames pass them: these soaks count how many, they do not fail on them.

mikroC (3 data bytes a frame): a request carries a 16-bit sequence number
and one byte of a keyed hash of (sequence, node); the slave answers with
the same sequence number and another hash byte. The soak knows every byte
it sent, so any delivery that differs is counted as corrupted; the slave
itself only has the hash byte, which lets 1 in 256 corruptions through.

G485: each cycle writes a block of user registers (8..23: sequence number,
random bytes, an 8-byte digest of node, sequence and random bytes) with the
master's check operation, then reads the block back and compares.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import random
import subprocess
import sys
import threading
import time
from typing import Any, Dict, List, Tuple

from .soak import FaultPlan, Sampler, _child, _teardown, _watch, running

_KEY = b"fap-soak"
G485_FIRST = 8          # first user register
G485_BLOCK = 16         # seq (4) + random (4) + digest (8)


def _say(*parts: Any) -> None:
    sys.stdout.write(" ".join(str(p) for p in parts) + "\n")
    sys.stdout.flush()


# -- mikroC ---------------------------------------------------------------

def mikroc_hash(tag: bytes, seq: int, node: int) -> int:
    """One byte of a keyed hash of (direction, sequence, node)."""
    return hashlib.blake2s(tag + seq.to_bytes(2, "big") + bytes([node]), key=_KEY).digest()[0]


def mikroc_request(seq: int, node: int) -> bytes:
    return seq.to_bytes(2, "big") + bytes([mikroc_hash(b"q", seq, node)])


def mikroc_reply(seq: int, node: int) -> bytes:
    return seq.to_bytes(2, "big") + bytes([mikroc_hash(b"r", seq, node)])


def mikroc_slave_child(path: str, node: int, baud: int) -> int:
    """A mikroC slave: report every delivery (raw data), answer the ones whose hash byte holds."""
    from fap_py.errors import FapError, FapTimeoutError
    from fap_py.mikroc import MikrocFrameError, Slave

    with Slave(path, baud, address=node) as s:
        _say("U")
        last = time.monotonic()
        while True:
            try:
                m = s.receive(timeout=0.2)
            except FapTimeoutError:
                m = None
            except MikrocFrameError:
                m = None
            except FapError:             # the bus went away: the soak is over
                return 0
            if m is not None:
                _say("R", m.address, m.data.hex() or "-")
                d = m.data
                if len(d) == 3 and d == mikroc_request(int.from_bytes(d[:2], "big"), node):
                    s.send(mikroc_reply(int.from_bytes(d[:2], "big"), node))
            if time.monotonic() - last >= 0.25:
                _say("T", json.dumps(dataclasses.asdict(s.stats)))
                last = time.monotonic()



def soak_mikroc(a: argparse.Namespace) -> Dict[str, Any]:
    from fap_py.errors import FapError, FapTimeoutError
    from fap_py.mikroc import Master, MikrocFrameError
    from fap_py.vbus import VirtualBus

    n = a.slaves
    bus = VirtualBus(ports=n + 1, baud=a.baud, seed=a.seed + 2)
    bus.set_fault(None, bit_error_rate=a.bus8_bit_error_rate, drop_rate=a.drop_rate)
    children: Dict[str, "subprocess.Popen[bytes]"] = {}
    threads: List[threading.Thread] = []
    # what each slave process reported: deliveries (address, data) and its last counters
    got: Dict[int, List[Tuple[int, bytes]]] = {i: [] for i in range(1, n + 1)}
    slave_stats: List[Dict[str, Any]] = []

    def reader(p: "subprocess.Popen[bytes]", node: int, up: threading.Event) -> None:
        assert p.stdout is not None
        st: Dict[str, Any] = {}
        slave_stats.append(st)
        for raw in p.stdout:
            f = raw.decode(errors="replace").split(" ", 1)
            tag, rest = f[0].strip(), (f[1].strip() if len(f) > 1 else "")
            if tag == "U":
                up.set()
            elif tag == "R":
                addr, data = rest.split()
                got[node].append((int(addr), b"" if data == "-" else bytes.fromhex(data)))
            elif tag == "T":
                st.clear()
                st.update(json.loads(rest))

    def start_slave(i: int) -> None:
        p = _child("mikroc", bus.paths[i], i, a.baud, a.seed + i, 0)
        _watch(p, i, children, threads, reader, i).wait(10)

    sampler = Sampler(a.sample, children)
    sampler.start()
    for i in range(1, n + 1):
        start_slave(i)
    master: Any = Master(bus.paths[0], a.baud)
    sent: Dict[Tuple[int, int], int] = {}          # (node, seq) -> 1
    replies: Dict[Tuple[int, int], int] = {}       # (node, seq) -> intact replies
    r_corrupt = r_late = r_wrong_node = no_reply = frame_errors = port_errors = reopens = 0
    seq = 0
    t0 = time.monotonic()
    plan = FaultPlan(a.seconds, t0)
    while running(a, t0):
        plan.step(children, start_slave, bus)
        node, s = 1 + seq % n, seq & 0xFFFF
        if master is None:              # the port vanished: open it again when it is back
            try:
                master = Master(bus.paths[0], a.baud)
                reopens += 1
            except FapError:
                time.sleep(0.05)         # still gone: pace the attempts
                continue
        try:
            master.send(node, mikroc_request(s, node))
        except FapError:
            port_errors += 1
            master.close()
            master = None
            continue
        sent[(node, s)] = 1
        seq += 1
        try:
            m = master.receive(timeout=a.timeout)
        except FapTimeoutError:
            no_reply += 1
            continue
        except MikrocFrameError:
            frame_errors += 1
            continue
        except FapError:
            port_errors += 1
            master.close()
            master = None
            continue
        t = time.monotonic() - t0
        d = m.data
        late = len(d) == 3 and (m.address, int.from_bytes(d[:2], "big")) in sent \
            and d == mikroc_reply(int.from_bytes(d[:2], "big"), m.address)
        if m.address != node and not late:
            r_wrong_node += 1            # a damaged address the check let through
        elif d == mikroc_reply(s, node) and m.address == node:
            replies[(node, s)] = replies.get((node, s), 0) + 1
            plan.good_exchange(node, t)
        elif late:
            r_late += 1                  # an intact reply to an earlier request (maybe another node's)
        else:
            r_corrupt += 1
    mstats = dataclasses.asdict(master.stats) if master is not None else {}
    if master is None:
        master = _Closed()
    time.sleep(0.3)                      # the last slave reports reach the readers
    bstats = _teardown(master, sampler, children, threads, bus)

    # master -> slaves: the soak knows every byte it sent
    intact = corrupt = dup = soak_byte_caught = 0
    for node, lst in got.items():
        seen: Dict[int, int] = {}
        for addr, d in lst:
            s = int.from_bytes(d[:2], "big") if len(d) == 3 else -1
            if addr == node and (node, s) in sent and d == mikroc_request(s, node):
                seen[s] = seen.get(s, 0) + 1
            else:
                corrupt += 1
                ok_byte = len(d) == 3 and d == mikroc_request(s, node)
                soak_byte_caught += not ok_byte
        intact += len(seen)
        dup += sum(c - 1 for c in seen.values())
    counters = {k: sum(int(st.get(k, 0)) for st in slave_stats) for k in ("errors", "damaged", "overruns")}
    s_intact = len(replies)
    s_dup = sum(c - 1 for c in replies.values())
    return {
        "protocol": "mikroc", "seconds": a.seconds, "slaves": n, "baud": a.baud,
        "faults": {"bit_error_rate": a.bus8_bit_error_rate, "drop_rate": a.drop_rate,
                   "bus_bit_errors": bstats.bit_errors, "bus_dropped_bytes": bstats.dropped,
                   "bus_collisions": bstats.collisions, "slave_killed": 1,
                   "port_disconnects": bstats.disconnects},
        "master_to_slaves": {"sent": len(sent), "delivered_intact": intact, "corrupted_undetected": corrupt,
                             "corrupted_caught_by_soak_byte": soak_byte_caught,
                             "duplicated": dup, "lost": len(sent) - intact,
                             "loss_counters": {"slave_damaged_for_it": counters["errors"],
                                               "slave_damaged_any": counters["damaged"],
                                               "slave_overruns": counters["overruns"],
                                               "master_send_port_errors": port_errors}},
        "slaves_to_master": {"replies_expected": len(sent), "delivered_intact": s_intact,
                             "corrupted_undetected": r_corrupt, "from_wrong_node": r_wrong_node,
                             "late_replies": r_late, "duplicated": s_dup,
                             "lost": len(sent) - s_intact,
                             "loss_counters": {"no_reply": no_reply, "frame_errors": frame_errors,
                                               "port_errors": port_errors}},
        "undetected_corruption_rate": round((corrupt + r_corrupt + r_wrong_node) / max(1, 2 * len(sent)), 6),
        "recovery_s": {"slave_restart_to_reply": round(plan.rec_restart, 3) if plan.rec_restart is not None else None,
                       "port_back_to_reply": round(plan.rec_port, 3) if plan.rec_port is not None else None},
        "master_reopens": reopens, "master_stats": mstats, "resources": sampler.summary(),
        # mikroC never sends a frame twice: a duplicate would be a bus or engine defect
        "ok": dup == 0 and s_dup == 0,
    }


class _Closed:
    """Stands in for a master that is already closed (the port was gone at the end)."""

    def close(self) -> None:
        pass


# -- G485 --------------------------------------------------------------------

def g485_block(seq: int, node: int, rnd: random.Random) -> bytes:
    """16 register values: sequence, 4 random bytes, 8 bytes of a digest of all and the node."""
    body = (seq & 0xFFFFFFFF).to_bytes(4, "big") + rnd.randbytes(4)
    return body + hashlib.blake2s(bytes([node]) + body, key=_KEY).digest()[:8]


def g485_intact(block: bytes, node: int) -> bool:
    return len(block) == G485_BLOCK and \
        hashlib.blake2s(bytes([node]) + block[:8], key=_KEY).digest()[:8] == block[8:]


def g485_sim_child(path: str, node: int, baud: int, seed: int) -> int:
    """A G485 simulator process with one device at address ``node``; reports its counters."""
    from fap_py.g485 import SimDevice, Simulator

    dev = SimDevice(node, seed=seed)
    with Simulator(path, [dev], baudrate=baud) as sim:
        _say("U")
        while sim.error is None:
            _say("T", json.dumps({"replies_sent": sim.replies_sent, "events": sim.events,
                                  "reopened": sim.reopened}))
            time.sleep(0.25)             # reporting period
    return 0


def soak_g485(a: argparse.Namespace) -> Dict[str, Any]:
    from fap_py.errors import FapError, PortError
    from fap_py.g485 import G485Master
    from fap_py.vbus import VirtualBus

    n = a.slaves
    rnd = random.Random(a.seed)
    bus = VirtualBus(ports=n + 1, baud=a.baud, seed=a.seed + 3)
    bus.set_fault(None, bit_error_rate=a.bus8_bit_error_rate, drop_rate=a.drop_rate)
    children: Dict[str, "subprocess.Popen[bytes]"] = {}
    threads: List[threading.Thread] = []
    sim_stats: Dict[str, Dict[str, Any]] = {}

    def reader(p: "subprocess.Popen[bytes]", name: str, up: threading.Event) -> None:
        assert p.stdout is not None
        for raw in p.stdout:
            f = raw.decode(errors="replace").split(" ", 1)
            if f[0].strip() == "U":
                up.set()
            elif f[0] == "T":
                sim_stats[name] = json.loads(f[1])

    def start_slave(i: int) -> None:
        p = _child("g485", bus.paths[i], i, a.baud, a.seed + i, 0)
        _watch(p, i, children, threads, reader, f"slave{i}.{len(threads)}").wait(10)

    sampler = Sampler(a.sample, children)
    sampler.start()
    for i in range(1, n + 1):
        start_slave(i)
    master = G485Master(bus.paths[0], a.baud, timeout=a.timeout, retries=a.retries)
    cycles = intact = corrupt = stale = w_fail = r_fail = port_errors = 0
    written: Dict[int, Dict[bytes, int]] = {i: {} for i in range(1, n + 1)}   # node -> block -> seq
    t0 = time.monotonic()
    plan = FaultPlan(a.seconds, t0)
    while running(a, t0):
        plan.step(children, start_slave, bus)
        node = 1 + cycles % n
        block = g485_block(cycles, node, rnd)
        cycles += 1
        written[node][block] = cycles
        try:
            master.write(node, G485_FIRST, block)
        except FapError as e:
            if isinstance(e, PortError):   # the master reopens the port before the next one
                port_errors += 1
                time.sleep(0.05)         # the port may still be gone: pace the attempts
            else:
                w_fail += 1
            continue
        try:
            back = master.read(node, G485_FIRST, G485_BLOCK)
        except FapError as e:
            if isinstance(e, PortError):
                port_errors += 1
                time.sleep(0.05)
            else:
                r_fail += 1
            continue
        t = time.monotonic() - t0
        if back == block:
            intact += 1
            plan.good_exchange(node, t)
        elif back in written[node] and g485_intact(back, node):
            stale += 1                   # an older block: this confirmed write did not land
        else:
            corrupt += 1
    mstats = dataclasses.asdict(master.stats)
    time.sleep(0.3)                      # the last simulator reports reach the readers
    bstats = _teardown(master, sampler, children, threads, bus)
    failed = w_fail + r_fail + port_errors
    return {
        "protocol": "g485", "seconds": a.seconds, "slaves": n, "baud": a.baud,
        "check": master.check.value, "retries": a.retries,
        "faults": {"bit_error_rate": a.bus8_bit_error_rate, "drop_rate": a.drop_rate,
                   "bus_bit_errors": bstats.bit_errors, "bus_dropped_bytes": bstats.dropped,
                   "bus_collisions": bstats.collisions, "slave_killed": 1,
                   "port_disconnects": bstats.disconnects},
        "sent": cycles, "delivered_intact": intact, "corrupted_undetected": corrupt,
        "stale_read": stale,
        # a write sets registers: a repeated write stores the same block again
        "duplicated": None,
        "lost": cycles - intact - corrupt - stale,
        "failed": {"write": w_fail, "read": r_fail, "port": port_errors},
        "every_loss_counted": cycles - intact - corrupt - stale == failed,
        "undetected_corruption_rate": round(corrupt / max(1, cycles), 6),
        "recovery_s": {"slave_restart_to_readback": round(plan.rec_restart, 3) if plan.rec_restart is not None else None,
                       "port_back_to_readback": round(plan.rec_port, 3) if plan.rec_port is not None else None},
        "master_stats": mstats, "simulators": sim_stats, "resources": sampler.summary(),
        "ok": True,
    }
