"""G485 soak: what its 8-bit check lets through, on the bus and on a simulated channel.

Same bus and faults as every soak, at ``bus8_bit_error_rate``: each cycle writes a block of
user registers (8..23: sequence number, random bytes, an 8-byte digest of node, sequence and
random bytes) with the master's check operation to a simulated device, then reads the block
back and compares. Corruption is measured, not failed on (``ok`` is always true).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import random
import threading
import time
from typing import Any, Dict, List

from .harness import Config, FaultPlan, Rig, channel_report, channel_soak, reports, running, say

NAME = "g485"
CHECK8 = True       # an 8-bit frame check: corruption measured, not failed on
_KEY = b"fap-soak"
G485_FIRST = 8          # first user register
G485_BLOCK = 16         # seq (4) + random (4) + digest (8)


def duration(cfg: Config) -> float:
    """The bus soak, then the channel model."""
    return cfg.seconds + cfg.check8_seconds


def g485_block(seq: int, node: int, rnd: random.Random) -> bytes:
    """16 register values: sequence, 4 random bytes, 8 bytes of a digest of all and the node."""
    body = (seq & 0xFFFFFFFF).to_bytes(4, "big") + rnd.randbytes(4)
    return body + hashlib.blake2s(bytes([node]) + body, key=_KEY).digest()[:8]


def g485_intact(block: bytes, node: int) -> bool:
    return len(block) == G485_BLOCK and \
        hashlib.blake2s(bytes([node]) + block[:8], key=_KEY).digest()[:8] == block[8:]


def child(path: str, node: int, baud: int, seed: int, rate: float, until: float) -> int:
    """A G485 simulator process with one device at address ``node``; reports its counters."""
    from fap_py.g485 import SimDevice, Simulator

    dev = SimDevice(node, seed=seed)
    with Simulator(path, [dev], baudrate=baud) as sim:
        say("U")
        while sim.error is None:
            say("T", json.dumps({"replies_sent": sim.replies_sent, "events": sim.events,
                                 "reopened": sim.reopened}))
            time.sleep(0.25)             # reporting period
    return 0


def run(cfg: Config) -> Dict[str, Any]:
    """The bus soak, with the channel model's figure under ``channel``."""
    res = _bus(cfg)
    res["channel"] = channel_soak(NAME, cfg, _channel_frame, _channel_decode)
    return res


def _channel_frame(rnd: random.Random) -> bytes:
    from fap_py import g485
    from fap_py.g485 import codec

    data = rnd.randbytes(rnd.randint(1, 12))
    return codec.encode_write(rnd.randint(g485.NODE_MIN, g485.NODE_MAX), rnd.randint(1, 100 - len(data) + 1), data)


def _channel_decode(wire: bytes) -> List[bytes]:
    from fap_py.g485 import codec

    p = codec.Parser()
    return [e.raw for e in p.feed(wire) + p.expire() if isinstance(e, codec.Packet)]


def _bus(cfg: Config) -> Dict[str, Any]:
    from fap_py.errors import FapError, PortError
    from fap_py.g485 import G485Master

    n = cfg.slaves
    rnd = random.Random(cfg.seed)
    rig = Rig(NAME, cfg, seed=cfg.seed + 3, bit_error_rate=cfg.bus8_bit_error_rate)
    sim_stats: Dict[str, Dict[str, Any]] = {}

    def reader(p: Any, name: str, up: threading.Event) -> None:
        for tag, rest in reports(p):
            if tag == "U":
                up.set()
            elif tag == "T":
                sim_stats[name] = json.loads(rest)

    def start_slave(i: int) -> None:
        rig.spawn(i, reader, f"slave{i}.{len(rig.threads)}").wait(10)

    for i in rig.nodes:
        start_slave(i)
    master = G485Master(rig.bus.paths[0], cfg.baud, timeout=cfg.timeout, retries=cfg.retries)
    cycles = intact = corrupt = stale = w_fail = r_fail = port_errors = 0
    written: Dict[int, Dict[bytes, int]] = {i: {} for i in rig.nodes}   # node -> block -> seq
    t0 = time.monotonic()
    plan = FaultPlan(cfg.seconds, t0)

    def failed_op(e: FapError) -> bool:
        """True for a failed transaction; a port error (the master reopens the port
        before the next one) is counted apart."""
        nonlocal port_errors
        if isinstance(e, PortError):
            port_errors += 1
            time.sleep(0.05)             # the port may still be gone: pace the attempts
            return False
        return True

    while running(cfg, t0):
        plan.step(rig.children, start_slave, rig.bus)
        node = 1 + cycles % n
        block = g485_block(cycles, node, rnd)
        cycles += 1
        written[node][block] = cycles
        try:
            master.write(node, G485_FIRST, block)
        except FapError as e:
            w_fail += failed_op(e)
            continue
        try:
            back = master.read(node, G485_FIRST, G485_BLOCK)
        except FapError as e:
            r_fail += failed_op(e)
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
    bstats = rig.close(master)
    failed = w_fail + r_fail + port_errors
    return {
        **rig.report(bstats, check=master.check.value, retries=cfg.retries),
        "sent": cycles, "delivered_intact": intact, "corrupted_undetected": corrupt,
        "stale_read": stale,
        # a write sets registers: a repeated write stores the same block again
        "duplicated": None,
        "lost": cycles - intact - corrupt - stale,
        "failed": {"write": w_fail, "read": r_fail, "port": port_errors},
        "every_loss_counted": cycles - intact - corrupt - stale == failed,
        "undetected_corruption_rate": round(corrupt / max(1, cycles), 6),
        "recovery_s": plan.recovery("readback"),
        "master_stats": mstats, "simulators": sim_stats, "resources": rig.sampler.summary(),
        "ok": True,
    }


def report(r: Dict[str, Any]) -> List[str]:
    """The summary lines of a report of :func:`run` (``.ci/soak.sh`` prints them)."""
    return [f"soak g485: bus BER {r['faults']['bit_error_rate']}/byte, {r['faults']['bus_bit_errors']} bit errors; "
            f"{r['sent']} write+read-back cycles, intact {r['delivered_intact']}, corrupted-undetected "
            f"{r['corrupted_undetected']}, stale {r['stale_read']}, lost {r['lost']} (failed {r['failed']}); "
            f"recovery {r['recovery_s']}"] + channel_report(r)
