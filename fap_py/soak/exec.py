"""exec async soak: the master sends numbered requests carrying a SHA-256 digest round the
slaves; a slave's handler checks the digest and answers with the request's number and a digest
of it, and reports every run. The report counts intact, corrupted and stale replies, failures,
and handler runs for one request (a duplicate, apart from the documented SeqNo-0 retry cost).
Fails (``ok`` false) on a corrupted or stale reply, a duplicate, or a corrupted request that
reached a handler."""
from __future__ import annotations

import hashlib
import random
import threading
import time
from typing import Any, Dict, List, Optional

from .harness import DIGEST, Config, FaultPlan, Rig, reports, running, say

NAME = "exec"
_ID = 8           # bytes of the request number at the start of a request and its reply


def _reply(req: bytes) -> bytes:
    return req[:_ID] + hashlib.sha256(b"reply" + req).digest()


def child(path: str, node: int, baud: int, seed: int, rate: float, until: float) -> int:
    """An exec async slave process: reports each intact request run (``H id seq``) and each
    corrupted one that reached the handler (``X``)."""
    from fap_py.execasync import Slave

    def handler(req: Any) -> Optional[bytes]:
        data = req.data
        if len(data) < _ID + DIGEST or hashlib.sha256(data[:-DIGEST]).digest() != data[-DIGEST:]:
            say("X")
            return None
        say("H", int.from_bytes(data[:_ID], "big"), req.seq)
        return _reply(data)

    with Slave(path, baud, node=node, handler=handler) as s:
        say("U")
        while True:
            try:
                s.serve(timeout=0.5)
            except Exception:            # the bus went away: the soak is over
                return 0


def run(cfg: Config) -> Dict[str, Any]:
    """The exec async bus soak and its report."""
    from fap_py.errors import FapError
    from fap_py.execasync import Master

    n = cfg.slaves
    rnd = random.Random(cfg.seed)
    rig = Rig(NAME, cfg, seed=cfg.seed + 1, bit_error_rate=cfg.bit_error_rate)
    execs: Dict[int, Dict[int, List[int]]] = {i: {} for i in rig.nodes}   # node -> id -> seqs
    bad_at_slave = [0]

    def reader(p: Any, node: int, up: threading.Event) -> None:
        for tag, rest in reports(p):
            if tag == "U":
                up.set()
            elif tag == "X":
                bad_at_slave[0] += 1
            elif tag == "H":
                mid, seq = rest.split()
                execs[node].setdefault(int(mid), []).append(int(seq))

    def start_slave(i: int) -> None:
        rig.spawn(i, reader, i).wait(10)

    for i in rig.nodes:
        start_slave(i)
    master = Master(rig.bus.paths[0], cfg.baud, timeout=cfg.timeout, retries=cfg.retries)
    t0 = time.monotonic()
    mid = 0
    ok = corrupted = stale = failures = port_errors = 0
    plan = FaultPlan(cfg.seconds, t0)
    while running(cfg, t0):
        plan.step(rig.children, start_slave, rig.bus)
        node = 1 + mid % n
        body = mid.to_bytes(_ID, "big") + rnd.randbytes(rnd.randint(8, 180))
        req = body + hashlib.sha256(body).digest()
        try:
            reply = master.transact(node, req)
        except FapError as e:
            if "port" in type(e).__name__.lower():
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
        if reply[:_ID] != req[:_ID]:
            stale += 1
        elif reply != _reply(req):
            corrupted += 1
        else:
            ok += 1
            plan.good_exchange(node, t)
        mid += 1
    time.sleep(0.3)                      # the last slave reports reach the readers
    st = master.stats
    mstats = {k: int(getattr(st, k)) for k in st.__dataclass_fields__}
    bstats = rig.close(master)
    dup = dup_seq0 = 0
    for ids in execs.values():
        for seqs in ids.values():
            if len(seqs) > 1:
                if all(s == 0 for s in seqs):
                    dup_seq0 += len(seqs) - 1     # the documented SeqNo-0 retry cost
                else:
                    dup += len(seqs) - 1
    return {
        **rig.report(bstats),
        "transactions": mid, "replies_intact": ok, "replies_corrupted": corrupted,
        "stale_replies": stale, "failed": failures, "port_errors": port_errors,
        "handler_runs": sum(len(s) for ids in execs.values() for s in ids.values()),
        "duplicated": dup, "duplicated_seq0_documented": dup_seq0,
        "corrupt_requests_reaching_handler": bad_at_slave[0],
        # every transaction that got no intact reply is in the master's failures
        "every_loss_counted": mid - ok - corrupted - stale == mstats["failures"],
        "recovery_s": plan.recovery("reply"),
        "master_stats": mstats, "resources": rig.sampler.summary(),
        "ok": corrupted == 0 and stale == 0 and dup == 0 and bad_at_slave[0] == 0,
    }


def report(r: Dict[str, Any]) -> List[str]:
    """The summary lines of a report of :func:`run` (``.ci/soak.sh`` prints them)."""
    return [f"soak exec: {r['transactions']} transactions, intact {r['replies_intact']}, corrupted "
            f"{r['replies_corrupted']}, stale {r['stale_replies']}, handler twice {r['duplicated']} "
            f"(+{r['duplicated_seq0_documented']} documented SeqNo 0), failed {r['failed']}, "
            f"recovery {r['recovery_s']}"]
