"""The protocol-free part of the fault soak: configuration, fault plan, resource sampler, slave
processes and their report lines, and the bit-error channel model.

Nothing here names a protocol: a protocol's soak (``fap_py.soak.<name>``, found through
:mod:`fap_py._protocols`) builds a :class:`Rig` (the faulty paced bus, its slave processes,
the sampler), runs its master against it under a :class:`FaultPlan`, and returns its report.
A slave process is ``python -m fap_py.soak --child NAME ...``: it runs the plug-in's
``child(path, node, baud, seed, rate, until)`` and talks to the soak through stdout lines
``TAG rest`` (:func:`say`, :func:`reports`).
"""
from __future__ import annotations

import hashlib
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
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple

log = logging.getLogger("fap_py.soak")

#: argv[1] of a slave process (``python -m fap_py.soak --child NAME ...``)
CHILD_FLAG = "--child"


def _default_baud() -> int:
    from ..rs485 import DEFAULT_BAUD

    return DEFAULT_BAUD


@dataclass
class Config:
    """One soak run's settings (``fap soak`` options of the same names)."""

    seconds: float = 30.0               #: each protocol's bus soak
    slaves: int = 3                     #: slave processes, nodes 1..slaves
    baud: int = field(default_factory=_default_baud)   #: paced bus rate
    bit_error_rate: float = 2e-5        #: per byte, every port
    drop_rate: float = 2e-5             #: per byte, every port
    bus8_bit_error_rate: float = 0.005  #: bus soak of a protocol with an 8-bit check
    timeout: float = 0.1                #: a request/reply master's reply timeout
    retries: int = 3                    #: ... and its extra attempts
    master_rate: float = 25.0           #: messages/s a queueing master sends
    slave_rate: float = 10.0            #: messages/s each queueing slave sends
    check8_seconds: float = 5.0         #: run time of the channel model
    check8_ber: float = 0.01            #: its bit error rate
    sample: float = 1.0                 #: resource sampling period, seconds
    seed: int = 12                      #: seed of every random choice and fault
    stop: Optional[threading.Event] = None   #: set: the soak loops end early


def running(cfg: Config, t0: float, seconds: Optional[float] = None) -> bool:
    """True while one protocol's soak goes on: its time (``seconds``, default
    ``cfg.seconds``) is not up and no SIGINT/SIGTERM came (``cfg.stop``)."""
    return (time.monotonic() - t0 < (cfg.seconds if seconds is None else seconds)
            and not (cfg.stop is not None and cfg.stop.is_set()))


def _plugin(protocol: str) -> Any:
    from .. import _protocols

    return _protocols.get(protocol).plugin("soak")


def duration(protocol: str, cfg: Config) -> float:
    """How long ``protocol``'s soak runs: its plug-in's ``duration(cfg)``, else ``cfg.seconds``."""
    fn = getattr(_plugin(protocol), "duration", None)
    return float(fn(cfg)) if fn is not None else cfg.seconds


def max_slaves(protocol: str) -> int:
    """Slave processes a soak of ``protocol`` can run: nodes 1..N must be addresses of the
    protocol (below its broadcast address) and ports of one virtual bus."""
    from .. import _protocols
    from ..vbus import MAX_PORTS

    p = _protocols.get(protocol)
    top = p.node_max
    if p.broadcast is not None and 1 <= p.broadcast <= top:
        top = p.broadcast - 1
    return max(0, min(top - max(1, p.node_min) + 1, MAX_PORTS - 1))


# -- faults -----------------------------------------------------------------------

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

    def step(self, children: Dict[str, Any], start_slave: Callable[[int], Any], bus: Any,
             on_kill: Optional[Callable[[], None]] = None) -> float:
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

    def recovery(self, what: str) -> Dict[str, Optional[float]]:
        """The report's recovery times: restart and port back to the first good ``what``."""
        def r(v: Optional[float]) -> Optional[float]:
            return round(v, 3) if v is not None else None
        return {f"slave_restart_to_{what}": r(self.rec_restart), f"port_back_to_{what}": r(self.rec_port)}


# -- messages -----------------------------------------------------------------------

DIGEST = 32
_HDR = struct.Struct(">BBHI")      # src, dst, incarnation, seq


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


# -- resources --------------------------------------------------------------------

def proc_sample(pid: int) -> Optional[Dict[str, int]]:
    """RSS (KiB), threads and open fds of a process (Linux /proc)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            status = f.read()
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


# -- slave processes ----------------------------------------------------------------

_say_lock = threading.Lock()


def say(*parts: Any) -> None:
    """In a slave process: one report line ``TAG rest`` to the soak (thread-safe)."""
    with _say_lock:
        sys.stdout.write(" ".join(str(p) for p in parts) + "\n")
        sys.stdout.flush()


def reports(p: "subprocess.Popen[bytes]") -> Iterator[Tuple[str, str]]:
    """In the soak: ``(tag, rest)`` of each line a slave process says, until it ends."""
    assert p.stdout is not None
    for raw in p.stdout:
        tag, _, rest = raw.decode(errors="replace").strip().partition(" ")
        if tag:
            yield tag, rest.strip()


def spawn(protocol: str, path: str, node: int, baud: int, seed: int, rate: float = 0.0,
          until: float = 0.0) -> "subprocess.Popen[bytes]":
    """A slave process running ``protocol``'s plug-in ``child(path, node, baud, seed, rate, until)``."""
    import fap_py

    # run from the directory holding the fap_py this process uses, so the
    # child imports the same (built) package, not a source tree in the cwd
    home = os.path.dirname(os.path.dirname(os.path.abspath(fap_py.__file__)))
    return subprocess.Popen([sys.executable, "-m", "fap_py.soak", CHILD_FLAG, protocol, path,
                             str(node), str(baud), str(seed), str(rate), str(until)],
                            stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, cwd=home)


def _die_with_parent() -> None:
    """A slave process must not outlive an interrupted soak (Linux prctl)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def child_main(argv: Sequence[str]) -> int:
    """Body of ``python -m fap_py.soak --child NAME PATH NODE BAUD SEED RATE UNTIL``."""
    _die_with_parent()
    name, path, node, baud, seed, rate, until = argv[:7]
    try:
        code: int = _plugin(name).child(path, int(node), int(baud), int(seed), float(rate), float(until))
        return code
    except (KeyboardInterrupt, BrokenPipeError):
        return 0


class Rig:
    """What one protocol's bus soak runs on: the paced virtual bus with ``cfg.slaves + 1``
    ports and bit errors and drops on all of them (port 0 is the master's), slave processes
    on ports 1.. with a thread reading each one's reports, and the resource sampler."""

    def __init__(self, protocol: str, cfg: Config, *, seed: int, bit_error_rate: float) -> None:
        from ..vbus import VirtualBus

        self.protocol, self.cfg, self.bit_error_rate = protocol, cfg, bit_error_rate
        self.bus = VirtualBus(ports=cfg.slaves + 1, baud=cfg.baud, seed=seed)
        self.bus.set_fault(None, bit_error_rate=bit_error_rate, drop_rate=cfg.drop_rate)
        self.children: "Dict[str, subprocess.Popen[bytes]]" = {}
        self.threads: List[threading.Thread] = []
        self.sampler = Sampler(cfg.sample, self.children)
        self.sampler.start()

    @property
    def nodes(self) -> range:
        """The slaves' node numbers (= their bus ports)."""
        return range(1, self.cfg.slaves + 1)

    def spawn(self, i: int, reader: Callable[..., None], key: Any, rate: float = 0.0,
              until: float = 0.0) -> threading.Event:
        """Start slave ``i``'s process (it replaces a killed one) and the thread running
        ``reader(process, key, up)``; ``up`` is set when the child says it is up."""
        p = spawn(self.protocol, self.bus.paths[i], i, self.cfg.baud, self.cfg.seed + i, rate, until)
        up = threading.Event()
        self.children[f"slave{i}"] = p
        t = threading.Thread(target=reader, args=(p, key, up), daemon=True)
        t.start()
        self.threads.append(t)
        return up

    def thread(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` in a daemon thread joined by :meth:`close`."""
        t = threading.Thread(target=fn, daemon=True)
        t.start()
        self.threads.append(t)

    def close(self, master: Any) -> Any:
        """Stop the sampler, close ``master`` (None: already gone), kill the slave processes,
        join the threads; return the bus counters (read before the bus closes)."""
        self.sampler.stop.set()
        self.sampler.join()
        if master is not None:
            master.close()
        for p in self.children.values():
            p.kill()
            p.wait()
        for th in self.threads:
            th.join(timeout=2)
        bstats = self.bus.stats
        self.bus.close()
        return bstats

    def faults(self, bstats: Any) -> Dict[str, Any]:
        """The report's ``faults``: what was set and what the bus did."""
        return {"bit_error_rate": self.bit_error_rate, "drop_rate": self.cfg.drop_rate,
                "bus_bit_errors": bstats.bit_errors, "bus_dropped_bytes": bstats.dropped,
                "bus_collisions": bstats.collisions, "slave_killed": 1,
                "port_disconnects": bstats.disconnects}

    def report(self, bstats: Any, **fields: Any) -> Dict[str, Any]:
        """A report's head (protocol, run, faults) followed by ``fields``."""
        return {"protocol": self.protocol, "seconds": self.cfg.seconds, "slaves": self.cfg.slaves,
                "baud": self.cfg.baud, **fields, "faults": self.faults(bstats)}


# -- channel model ------------------------------------------------------------------

def channel(rnd: random.Random, frame: bytes, ber: float) -> bytes:
    """``frame`` through a channel that flips each bit with probability ``ber``."""
    out = bytearray(frame)
    for i in range(len(out)):
        for bit in range(8):
            if rnd.random() < ber:
                out[i] ^= 1 << bit
    return bytes(out)


def channel_soak(protocol: str, cfg: Config, make_frame: Callable[[random.Random], bytes],
                 decode: Callable[[bytes], List[bytes]]) -> Dict[str, Any]:
    """What a frame check lets through, without a bus: frames from ``make_frame`` go through
    :func:`channel` at ``cfg.check8_ber`` for ``cfg.check8_seconds``; ``decode`` returns the
    frames (as bytes) a fresh decoder delivers from what arrived."""
    rnd = random.Random(cfg.seed)
    ber = cfg.check8_ber
    sent = intact = detected = undetected = damaged = lost = 0
    t0 = time.monotonic()
    while running(cfg, t0, cfg.check8_seconds):
        frame = make_frame(rnd)
        wire = channel(rnd, frame, ber)
        sent += 1
        damaged += wire != frame
        got = decode(wire)
        if not got:
            detected += wire != frame
            lost += wire == frame
        elif len(got) == 1 and got[0] == frame:
            intact += 1
        else:
            undetected += 1
    return {"protocol": protocol, "bit_error_rate": ber, "frames": sent, "damaged_on_wire": damaged,
            "delivered_intact": intact, "damage_detected": detected,
            "damage_undetected": undetected, "clean_but_lost": lost,
            "undetected_per_damaged_frame": round(undetected / damaged, 5) if damaged else 0.0}


def channel_report(r: Dict[str, Any]) -> List[str]:
    """The lines every report with a channel model (``channel_soak``) ends with: the
    undetected corruption rate on the bus, then what the channel model measured."""
    p, c = r["protocol"], r["channel"]
    return [f"soak {p}: UNDETECTED CORRUPTION RATE on the bus {r['undetected_corruption_rate']} per message",
            f"soak {p} channel: {c['frames']} frames at bit error rate {c['bit_error_rate']}: "
            f"{c['damaged_on_wire']} damaged, {c['damage_undetected']} passed the 8-bit check "
            f"({c['undetected_per_damaged_frame']} per damaged frame)"]
