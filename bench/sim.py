"""``fap sim`` against the responders it stands in for: the rows of issue 35.

For each request/reply protocol, one paced 115200 bus carries ``fap sim`` with the protocol's
whole address range (exec async 1..254, mikroC's range, G485 1..126) and a master scanning
every node in turn; a second bus of the same pace carries the responder the sim is measured
against (the C slave engine of ``fap exec slave`` / ``fap mikroc slave`` answering one node,
the bare responder on the link; for G485 the simulator class ``fap g485 sim`` ran before it
became a case of ``fap sim``, ``fap_py.g485.Simulator``, with the same 126 devices).
The two are measured in interleaved batches (a load swing slows both alike within a round);
the row is the median of the per-round ratios of exchanges/s. The idle row is each sim's CPU
while no master talks (``/proc/<pid>/stat``, 2 s). FAP's simulated slaves are the C slave
engine itself (``fap_py.sim.protocols.fap``), so its row is the master's poll cycles/s with 31
simulated slaves and the sim's idle CPU.

The replay row records 5,000 exec async exchanges (10,000 frames) through the sim on a
capturing virtual bus, replays the capture with ``fap sim --replay`` on another capturing bus,
and compares the replies byte for byte and each reply's delay after its request with the
recorded one: p99 of the difference, in character times (10 bits at the baud).

    python bench/sim.py            # prints the rows
    python -m bench --sections parts   # with the other parts' rows
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

if __package__ in (None, ""):      # python bench/sim.py: the checkout's bench, the installed fap_py
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from bench import use_installed_fap_py

    use_installed_fap_py()

from bench.stats import loadavg, proc_cpu
from bench.targets import Target, table

BAUD = 115200
SHARE = 95.0          # % of the responder it stands in for
IDLE = 2.0            # % of a core, an idle sim of every node
REPLAY_CHARS = 1.0    # p99 of |replayed - recorded| reply delay, character times
GOAL_SCAN = f"fap sim, the whole address range, exchanges/s >= {SHARE:g} % of the responder it stands in for"


#: the G485 reference: fap_py.g485.Simulator with one SimDevice per address (seed N, as
#: ``fap g485 sim`` seeded its devices before it ran the sim room), a JSON ready line
_G485_REFERENCE = """
import json, signal, sys, threading
from fap_py.g485 import SimDevice, Simulator
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
with Simulator(sys.argv[1], [SimDevice(int(a), seed=int(a)) for a in sys.argv[2:]], baudrate=115200) as sim:
    print(json.dumps({"event": "ready", "port": sim.name}), flush=True)
    stop.wait()
"""


def _fap(*args: str) -> List[str]:
    return [sys.executable, "-m", "fap_py", *args]


class _Proc:
    """A responder process that prints a JSON ``ready`` line (``--json``) before it serves."""

    def __init__(self, argv: Sequence[str], timeout: float = 60.0) -> None:
        self.p = subprocess.Popen(list(argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + timeout
        self.ready: Dict[str, Any] = {}
        assert self.p.stdout is not None
        while time.monotonic() < deadline:
            line = self.p.stdout.readline()
            if not line:
                raise RuntimeError(f"{' '.join(argv[2:])} exited: {self.p.stderr.read() if self.p.stderr else ''}")
            try:
                obj = json.loads(line)
            except ValueError:
                continue
            if obj.get("event") == "ready":
                self.ready = obj
                return
        raise RuntimeError(f"{' '.join(argv[2:])}: no ready line in {timeout:g} s")

    def cpu_share(self, seconds: float) -> float:
        """The process's CPU over ``seconds`` of wall time, % of a core."""
        c0, t0 = proc_cpu(self.p.pid), time.monotonic()
        time.sleep(seconds)
        return 100.0 * (proc_cpu(self.p.pid) - c0) / (time.monotonic() - t0)

    def close(self) -> None:
        self.p.terminate()
        try:
            self.p.communicate(timeout=10)
        except subprocess.TimeoutExpired:   # pragma: no cover
            self.p.kill()
            self.p.communicate()


def _addresses(protocol: str) -> List[int]:
    """Every node address of the protocol (its sim plug-in's range, the reserved ones left out)."""
    from fap_py.sim import plugin

    p = plugin(protocol)
    reserved = set(getattr(p, "ADDRESS_RESERVED", ()))
    return [a for a in range(p.ADDRESS_MIN, p.ADDRESS_MAX + 1) if a not in reserved]


def _config(path: str, protocol: str, addresses: Sequence[int], port: Optional[str]) -> str:
    where = f'port = "{port}"\n' if port else ""
    runs: List[List[int]] = []
    for a in addresses:              # one node entry per run of consecutive addresses
        if runs and runs[-1][1] == a - 1:
            runs[-1][1] = a
        else:
            runs.append([a, a])
    with open(path, "w") as fh:
        fh.write(f'[[bus]]\nprotocol = "{protocol}"\nbaud = {BAUD}\n{where}')
        for lo, hi in runs:
            fh.write(f'[[bus.node]]\nrange = [{lo}, {hi}]\n')
    return path


def _batch(call: Callable[[int], Any], nodes: Sequence[int], seconds: float, start: int) -> Tuple[int, float, int]:
    """Exchanges for ``seconds``, node after node from index ``start``: (count, elapsed, next index)."""
    n, i = 0, start
    t0 = time.monotonic()
    while True:
        call(nodes[i % len(nodes)])
        n += 1
        i += 1
        el = time.monotonic() - t0
        if el >= seconds:
            return n, el, i


def _scan(protocol: str, rounds: int, seconds: float, tmp: str) -> Dict[str, Any]:
    from fap_py import execasync, mikroc
    from fap_py.g485 import G485Master
    from fap_py.vbus import VirtualBus

    sim_nodes = _addresses(protocol)
    with VirtualBus(ports=2, baud=BAUD, seed=1) as direct, VirtualBus(ports=2, baud=BAUD, seed=2) as simbus:
        if protocol == "exec":
            ref = _Proc(_fap("exec", "slave", "--port", direct.paths[1], "--node", "1", "--json"))
        elif protocol == "mikroc":
            ref = _Proc(_fap("mikroc", "slave", "--port", direct.paths[1], "--address", "1", "--json"))
        else:
            # the G485 simulator class fap g485 sim ran before it became a fap sim site
            ref = _Proc([sys.executable, "-c", _G485_REFERENCE, direct.paths[1], *map(str, sim_nodes)])
        sim = _Proc(_fap("sim", _config(os.path.join(tmp, f"{protocol}.toml"), protocol, sim_nodes,
                                        simbus.paths[1]), "--json"))
        try:
            idle = sim.cpu_share(2.0)
            masters = []
            for path in (direct.paths[0], simbus.paths[0]):
                if protocol == "exec":
                    m: Any = execasync.Master(path, BAUD, timeout=0.5, retries=0)
                    masters.append((m, lambda n, m=m: m.transact(n, b"\x01\x02\x03\x04\x05\x06\x07\x08")))
                elif protocol == "mikroc":
                    m = mikroc.Master(path, BAUD)
                    masters.append((m, lambda n, m=m: m.request(n, b"\x01\x02", timeout=0.5)))
                else:
                    m = G485Master(path, BAUD, timeout=0.5, retries=0, check="none")
                    masters.append((m, lambda n, m=m: m.read_register(n, 1)))
            ref_nodes = [1] if protocol in ("exec", "mikroc") else sim_nodes
            ratios, rates = [], {"ref": [], "sim": []}
            at = [0, 0]
            load0 = loadavg()
            for _ in range(rounds):
                n0, e0, at[0] = _batch(masters[0][1], ref_nodes, seconds, at[0])
                n1, e1, at[1] = _batch(masters[1][1], sim_nodes, seconds, at[1])
                rates["ref"].append(n0 / e0)
                rates["sim"].append(n1 / e1)
                ratios.append((n1 / e1) / (n0 / e0))
            for m, _ in masters:
                m.close()
            return {"protocol": protocol, "nodes": len(sim_nodes), "ratio": statistics.median(ratios),
                    "ratio_min": min(ratios), "ratio_max": max(ratios),
                    "ref_rate": statistics.median(rates["ref"]), "sim_rate": statistics.median(rates["sim"]),
                    "idle_cpu": idle, "covered": at[1] >= len(sim_nodes), "load": f"{load0} -> {loadavg()}"}
        finally:
            sim.close()
            ref.close()


def _fap_row(tmp: str) -> Dict[str, Any]:
    from fap_py import fap

    path = os.path.join(tmp, "fap.toml")
    with open(path, "w") as fh:
        fh.write(f'[[bus]]\nprotocol = "fap"\nbaud = {BAUD}\n[[bus.node]]\nrange = [1, 31]\n')
    sim = _Proc(_fap("sim", path, "--json"))
    try:
        idle = sim.cpu_share(2.0)
        port = sim.ready["buses"][0]["master_port"]
        with fap.Master(port, BAUD, slaves=list(range(1, 32))) as m:
            m.wait_active(list(range(1, 32)), timeout=30)
            s0, t0 = m.stats, time.monotonic()
            time.sleep(2.0)
            s1, el = m.stats, time.monotonic() - t0
        polls = (s1.polls - s0.polls) if hasattr(s1, "polls") else None
        return {"idle_cpu": idle, "polls_per_s": None if polls is None else polls / el}
    finally:
        sim.close()


def _delays(capture: str) -> Dict[bytes, List[Tuple[bytes, float]]]:
    """Request bytes -> [(reply, delay s)] of an exec async capture: the replay's own pairing
    (:func:`fap_py.sim._replay.build_table`), so recording and replay are read alike."""
    from fap_py.sim._replay import build_table
    from fap_py.vbus import read_capture

    return build_table(read_capture(capture), "exec").entries


def _replay_row(tmp: str, exchanges: int, realtime: Optional[str] = None) -> Dict[str, Any]:
    from fap_py import execasync
    from fap_py.vbus import VirtualBus

    rec_cap, rep_cap = os.path.join(tmp, "rec.cap"), os.path.join(tmp, "rep.cap")
    payload = [i.to_bytes(4, "big") for i in range(exchanges)]
    rt = ["--realtime", realtime] if realtime else []   # the sims' port threads; the buses' own
    with VirtualBus(ports=2, baud=BAUD, capture=rec_cap, realtime=realtime) as bus:
        sim = _Proc(_fap("sim", _config(os.path.join(tmp, "echo.toml"), "exec", [1], bus.paths[1]), "--json",
                         *(rt and ["--port", bus.paths[1], *rt])))
        try:
            with execasync.Master(bus.paths[0], BAUD, timeout=0.5, retries=0) as m:
                recorded = [m.transact(1, p) for p in payload]
        finally:
            sim.close()
    with VirtualBus(ports=2, baud=BAUD, capture=rep_cap, realtime=realtime) as bus:
        rp = _Proc(_fap("sim", "--replay", rec_cap, "--protocol", "exec", "--port", bus.paths[1],
                        "--baud", str(BAUD), "--json", *rt))
        try:
            with execasync.Master(bus.paths[0], BAUD, timeout=0.5, retries=0) as m:
                replayed = [m.transact(1, p) for p in payload]
        finally:
            rp.close()
    a, b = _delays(rec_cap), _delays(rep_cap)
    char = 10.0 / BAUD
    pairs = [(x, y) for req in a for x, y in zip(a[req], b.get(req, ()))]
    signed = sorted((y[1] - x[1]) / char for x, y in pairs)     # + : the replay was later
    diffs = sorted(abs(d) for d in signed)
    exact = sum(x[0] == y[0] for x, y in pairs)
    n = sum(len(v) for v in a.values())
    return {"frames": 2 * n, "byte_exact": replayed == recorded and exact == n == sum(len(v) for v in b.values()),
            "p99_chars": diffs[int(0.99 * (len(diffs) - 1))] if diffs else None,
            "p50_chars": statistics.median(diffs) if diffs else None,
            "max_chars": diffs[-1] if diffs else None,
            "median_signed_chars": statistics.median(signed) if signed else None}


#: the row groups ``--only`` picks from
PARTS = ("scan", "fap", "replay")


def measure(rounds: int = 7, seconds: float = 0.4, exchanges: int = 5000,
            only: Sequence[str] = PARTS, realtime: Optional[str] = None) -> Dict[str, Any]:
    out: Dict[str, Any] = {"load": loadavg()}
    with tempfile.TemporaryDirectory(prefix="fap-bench-sim-") as tmp:
        if "scan" in only:
            out.update({p: _scan(p, rounds, seconds, tmp) for p in ("exec", "mikroc", "g485")})
        if "fap" in only:
            out["fap"] = _fap_row(tmp)
        if "replay" in only:
            out["replay"] = _replay_row(tmp, exchanges, realtime)
            out["replay"]["realtime"] = realtime
    out["load_after"] = loadavg()
    return out


def to_targets(res: Dict[str, Any]) -> List[Target]:
    rows: List[Target] = []
    for p in ("exec", "mikroc", "g485"):
        if p not in res:
            continue
        r = res[p]
        ref = "fap_py.g485.Simulator, the same 126 devices" if p == "g485" else f"the C slave engine (fap {p} slave), one node"
        rows.append(Target(f"sim-scan-{p}", GOAL_SCAN, 100 * r["ratio"], SHARE, True, "%",
                           f"{r['nodes']} nodes, {r['sim_rate']:.0f} vs {r['ref_rate']:.0f} exchanges/s against {ref}; "
                           f"per-round ratios {100 * r['ratio_min']:.0f}-{100 * r['ratio_max']:.0f} %; "
                           f"load {r['load']}"))
    for p in ("exec", "mikroc", "g485", "fap"):
        if p not in res:
            continue
        r = res[p]
        note = f"{res['fap']['polls_per_s']:.0f} poll cycles/s of a master with the 31 slaves" \
            if p == "fap" and res["fap"].get("polls_per_s") else "no master on the bus, 2 s"
        rows.append(Target(f"sim-idle-{p}", f"an idle fap sim of every {p} node < {IDLE:g} % of a core",
                           r["idle_cpu"], IDLE, False, "%", note))
    if "replay" not in res:
        return rows
    r = res["replay"]
    rows.append(Target("sim-replay-timing", f"replay of a 10,000-frame capture: byte-exact, reply delay "
                       f"within {REPLAY_CHARS:g} character time of the recording (p99)",
                       r["p99_chars"] if r["byte_exact"] else None, REPLAY_CHARS, False, "chars",
                       f"{r['frames']} frames, byte-exact {r['byte_exact']}, p50 {r['p50_chars']:.2f} chars, "
                       f"max {r['max_chars']:.1f}, signed median {r['median_signed_chars']:+.2f}; load "
                       f"{res['load']} -> {res['load_after']}"
                       + (f"; real-time {r['realtime']}" if r.get("realtime") else "")
                       if r["p50_chars"] is not None else "no exchange measured"))
    return rows


def targets(rounds: int = 7) -> List[Target]:
    """The bench runner's entry (bench/issue24.py PARTS)."""
    return to_targets(measure(rounds=max(3, rounds)))


def main(argv: Optional[List[str]] = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--seconds", type=float, default=0.4, help="one batch of one master")
    ap.add_argument("--exchanges", type=int, default=5000, help="the replay's recorded exchanges")
    ap.add_argument("--json", metavar="FILE", help="write the raw results here")
    ap.add_argument("--only", choices=PARTS, action="append",
                    help="measure only these rows (repeat; default all): scan, fap, replay")
    ap.add_argument("--realtime", metavar="SPEC", help="the replay row: the sims' port threads and the "
                    "virtual buses at this real-time spec (docs/realtime.md, e.g. fifo:50)")
    a = ap.parse_args(argv)
    res = measure(a.rounds, a.seconds, a.exchanges, a.only or PARTS, a.realtime)
    print(table(to_targets(res)), end="")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
