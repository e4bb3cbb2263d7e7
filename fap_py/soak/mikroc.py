"""mikroC soak: what its 8-bit check lets through, on the bus and on a simulated channel.

Same bus and faults as every soak, at ``bus8_bit_error_rate``: a request (3 data bytes)
carries a 16-bit sequence number and one byte of a keyed hash of (sequence, node); the slave
answers with the same sequence number and another hash byte. The soak knows every byte it
sent, so any delivery that differs is counted as corrupted; the slave itself only has the
hash byte, which lets 1 in 256 corruptions through. Corruption is measured, not failed on;
``ok`` is false only when a frame was delivered twice (mikroC never sends one twice).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import random
import threading
import time
from typing import Any, Dict, List, Tuple

from .harness import Config, FaultPlan, Rig, channel_report, channel_soak, reports, running, say

NAME = "mikroc"
CHECK8 = True       # an 8-bit frame check: corruption measured, not failed on
_KEY = b"fap-soak"


def duration(cfg: Config) -> float:
    """The bus soak, then the channel model."""
    return cfg.seconds + cfg.check8_seconds


def mikroc_hash(tag: bytes, seq: int, node: int) -> int:
    """One byte of a keyed hash of (direction, sequence, node)."""
    return hashlib.blake2s(tag + seq.to_bytes(2, "big") + bytes([node]), key=_KEY).digest()[0]


def mikroc_request(seq: int, node: int) -> bytes:
    return seq.to_bytes(2, "big") + bytes([mikroc_hash(b"q", seq, node)])


def mikroc_reply(seq: int, node: int) -> bytes:
    return seq.to_bytes(2, "big") + bytes([mikroc_hash(b"r", seq, node)])


def _seq(d: bytes) -> int:
    return int.from_bytes(d[:2], "big")


def child(path: str, node: int, baud: int, seed: int, rate: float, until: float) -> int:
    """A mikroC slave: report every delivery (raw data), answer the ones whose hash byte holds."""
    from fap_py.errors import FapError, FapTimeoutError
    from fap_py.mikroc import MikrocFrameError, Slave

    with Slave(path, baud, address=node) as s:
        say("U")
        last = time.monotonic()
        while True:
            try:
                m = s.receive(timeout=0.2)
            except (FapTimeoutError, MikrocFrameError):
                m = None
            except FapError:             # the bus went away: the soak is over
                return 0
            if m is not None:
                say("R", m.address, m.data.hex() or "-")
                d = m.data
                if len(d) == 3 and d == mikroc_request(_seq(d), node):
                    s.send(mikroc_reply(_seq(d), node))
            if time.monotonic() - last >= 0.25:
                say("T", json.dumps(dataclasses.asdict(s.stats)))
                last = time.monotonic()


def run(cfg: Config) -> Dict[str, Any]:
    """The bus soak, with the channel model's figure under ``channel``."""
    res = _bus(cfg)
    res["channel"] = channel_soak(NAME, cfg, _channel_frame, _channel_decode)
    return res


def _channel_frame(rnd: random.Random) -> bytes:
    from fap_py import mikroc

    addr, data, fm = rnd.randrange(256), rnd.randbytes(rnd.randint(0, 3)), rnd.random() < 0.5
    return mikroc.encode(addr, data, from_master=fm)


def _channel_decode(wire: bytes) -> List[bytes]:
    from fap_py import mikroc

    return [mikroc.encode(e.address, e.data, from_master=e.from_master)
            for e in mikroc.Decoder().feed(wire) if isinstance(e, mikroc.Message)]


def _bus(cfg: Config) -> Dict[str, Any]:
    from fap_py.errors import FapError, FapTimeoutError
    from fap_py.mikroc import Master, MikrocFrameError

    n = cfg.slaves
    rig = Rig(NAME, cfg, seed=cfg.seed + 2, bit_error_rate=cfg.bus8_bit_error_rate)
    # what each slave process reported: deliveries (address, data) and its last counters
    got: Dict[int, List[Tuple[int, bytes]]] = {i: [] for i in rig.nodes}
    slave_stats: List[Dict[str, Any]] = []

    def reader(p: Any, node: int, up: threading.Event) -> None:
        st: Dict[str, Any] = {}
        slave_stats.append(st)
        for tag, rest in reports(p):
            if tag == "U":
                up.set()
            elif tag == "R":
                addr, data = rest.split()
                got[node].append((int(addr), b"" if data == "-" else bytes.fromhex(data)))
            elif tag == "T":
                st.clear()
                st.update(json.loads(rest))

    def start_slave(i: int) -> None:
        rig.spawn(i, reader, i).wait(10)

    for i in rig.nodes:
        start_slave(i)
    master: Any = Master(rig.bus.paths[0], cfg.baud)
    sent: Dict[Tuple[int, int], int] = {}          # (node, seq) -> 1
    replies: Dict[Tuple[int, int], int] = {}       # (node, seq) -> intact replies
    r_corrupt = r_late = r_wrong_node = no_reply = frame_errors = port_errors = reopens = 0
    seq = 0
    t0 = time.monotonic()
    plan = FaultPlan(cfg.seconds, t0)
    while running(cfg, t0):
        plan.step(rig.children, start_slave, rig.bus)
        node, s = 1 + seq % n, seq & 0xFFFF
        if master is None:              # the port vanished: open it again when it is back
            try:
                master = Master(rig.bus.paths[0], cfg.baud)
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
            m = master.receive(timeout=cfg.timeout)
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
        late = len(d) == 3 and (m.address, _seq(d)) in sent and d == mikroc_reply(_seq(d), m.address)
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
    time.sleep(0.3)                      # the last slave reports reach the readers
    bstats = rig.close(master)

    # master -> slaves: the soak knows every byte it sent
    intact = corrupt = dup = soak_byte_caught = 0
    for node, lst in got.items():
        seen: Dict[int, int] = {}
        for addr, d in lst:
            s = _seq(d) if len(d) == 3 else -1
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
        **rig.report(bstats),
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
        "recovery_s": plan.recovery("reply"),
        "master_reopens": reopens, "master_stats": mstats, "resources": rig.sampler.summary(),
        # mikroC never sends a frame twice: a duplicate would be a bus or engine defect
        "ok": dup == 0 and s_dup == 0,
    }


def report(r: Dict[str, Any]) -> List[str]:
    """The summary lines of a report of :func:`run` (``.ci/soak.sh`` prints them)."""
    a, b = r["master_to_slaves"], r["slaves_to_master"]
    return [f"soak mikroc: bus BER {r['faults']['bit_error_rate']}/byte, {r['faults']['bus_bit_errors']} bit errors; "
            f"m->s sent {a['sent']} intact {a['delivered_intact']} corrupted-undetected "
            f"{a['corrupted_undetected']} duplicated {a['duplicated']} lost {a['lost']}; "
            f"s->m intact {b['delivered_intact']} corrupted-undetected "
            f"{b['corrupted_undetected'] + b['from_wrong_node']} duplicated {b['duplicated']} "
            f"lost {b['lost']}; recovery {r['recovery_s']}"] + channel_report(r)
