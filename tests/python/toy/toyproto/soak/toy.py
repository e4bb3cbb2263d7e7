"""``fap soak --protocol toy``: the toy's soak plug-in, written only against fap_py.soak.harness.

The master sends random requests round the slave processes and checks that each reply is the
request reversed; the harness kills slave 1 and takes the master's port away, and the report
says how many exchanges came back intact, stale (the reply to an earlier request of that node:
the toy has no sequence numbers), corrupted or not at all. ``ok``: nothing corrupted.
"""
from __future__ import annotations

import random
import threading
import time
from typing import Any, Dict, Optional, Set

from fap_py.soak.harness import Config, FaultPlan, Rig, reports, running, say

NAME = "toy"


def child(path: str, node: int, baud: int, seed: int, rate: float, until: float) -> int:
    """A toy slave process: answers in its own thread; reports its counters (``T rx tx``)."""
    from toyproto.binding import Slave

    with Slave(path, node, baud).start() as s:
        say("U")
        while True:
            st = s.stats
            say("T", st.frames_rx, st.frames_tx)
            time.sleep(0.25)             # reporting period


def run(cfg: Config) -> Dict[str, Any]:
    """The toy bus soak and its report."""
    from fap_py.errors import FapError, PortError
    from toyproto.binding import MAX_DATA, Master

    rnd = random.Random(cfg.seed)
    rig = Rig(NAME, cfg, seed=cfg.seed + 5, bit_error_rate=cfg.bit_error_rate)
    answered: Dict[str, int] = {}        # slave process -> requests it answered

    def reader(p: Any, key: str, up: threading.Event) -> None:
        for tag, rest in reports(p):
            if tag == "U":
                up.set()
            elif tag == "T":
                answered[key] = int(rest.split()[1])

    def start_slave(i: int) -> None:
        rig.spawn(i, reader, f"slave{i}.{len(rig.threads)}").wait(10)

    for i in rig.nodes:
        start_slave(i)
    master: Optional[Master] = Master(rig.bus.paths[0], cfg.baud, timeout=cfg.timeout)
    sent = intact = stale = corrupted = failed = port_errors = 0
    earlier: Dict[int, Set[bytes]] = {i: set() for i in rig.nodes}   # node -> replies it owes
    t0 = time.monotonic()
    plan = FaultPlan(cfg.seconds, t0)
    while running(cfg, t0):
        plan.step(rig.children, start_slave, rig.bus)
        if master is None:               # the port went away: open it again when it is back
            try:
                master = Master(rig.bus.paths[0], cfg.baud, timeout=cfg.timeout)
            except FapError:
                time.sleep(0.05)         # still gone: pace the attempts
                continue
        node = 1 + sent % cfg.slaves
        data = rnd.randbytes(rnd.randint(1, MAX_DATA))
        sent += 1
        earlier[node].add(data[::-1])
        try:
            reply = master.request(node, data)
        except PortError:
            port_errors += 1
            master.close()
            master = None
            continue
        except FapError:
            failed += 1
            continue
        if reply == data[::-1]:
            intact += 1
            plan.good_exchange(node, time.monotonic() - t0)
        elif reply in earlier[node]:
            stale += 1                   # a late reply, read by the next request to that node
        else:
            corrupted += 1
    time.sleep(0.3)                      # the last slave reports reach the readers
    bstats = rig.close(master)
    return {
        **rig.report(bstats),
        "sent": sent, "delivered_intact": intact, "stale": stale, "corrupted": corrupted, "failed": failed,
        "port_errors": port_errors, "slave_answers": sum(answered.values()),
        "every_loss_counted": sent == intact + stale + corrupted + failed + port_errors,
        "recovery_s": plan.recovery("reply"), "resources": rig.sampler.summary(),
        "ok": corrupted == 0,
    }
