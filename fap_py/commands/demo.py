"""``fap demo``: a FAP master and three slaves on a virtual bus, in one process.

No hardware needed: a :class:`~fap_py.vbus.VirtualBus` provides four pty
ports wired as one RS-485 bus; a :class:`~fap_py.Master` and three
:class:`~fap_py.Slave` objects (each a libfap C engine) open them, exchange
messages both ways, one slave leaves and comes back, and the transcript
shows who sent what to whom, the slave events and the counters.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from typing import TYPE_CHECKING, List, Optional, TextIO

if TYPE_CHECKING:  # pragma: no cover
    from ..fap import Master, Node, Slave

SLAVE_IDS = (3, 7, 12)
WAIT_S = 10.0         # upper bound of every wait; the whole demo takes well under 1 s
# Protocol timing shortened for the demo (vendor defaults: 15 s, 1 s, 15 s).
DEMO_TIMING = dict(id_cycle=0.05, id_answer_timeout=0.1, data_done_timeout=0.3)


def register(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    p = sub.add_parser(
        "demo", help="run a FAP master and 3 slaves on a virtual bus and show the traffic",
        description="Create a virtual 4-port RS-485 bus, run a FAP master and three slaves "
        "(libfap's C engine through fap_py) on it in this process, exchange messages in "
        "both directions, let one slave leave and return, print a transcript. No hardware.")
    p.add_argument("--baud", type=int, default=115200,
                   help="line speed the nodes configure (default 115200)")
    p.add_argument("--paced", action="store_true",
                   help="let the virtual bus deliver bytes at --baud (10 bits/byte) like a "
                   "real wire; default: as fast as the ptys go")
    p.set_defaults(func=run)


class Transcript:
    """Timestamped, aligned lines."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.t0 = time.monotonic()

    def line(self, who: str, text: str) -> None:
        t = time.monotonic() - self.t0
        self.out.write(f"[{t:7.3f} s] {who:<9} {text}\n")
        self.out.flush()

    def plain(self, text: str = "") -> None:
        self.out.write(text + "\n")
        self.out.flush()


def _show(data: bytes) -> str:
    if len(data) > 40:
        return f"{len(data)} bytes ({data[:8].hex(' ')} ... {data[-4:].hex(' ')})"
    try:
        text = data.decode("ascii")
        if text.isprintable():
            return f'"{text}" ({len(data)} bytes)'
    except UnicodeDecodeError:
        pass
    return f"{data.hex(' ')} ({len(data)} bytes)"


def _name(node_id: int) -> str:
    return "master" if node_id == 0 else f"slave {node_id}"


def run(args: argparse.Namespace, out: Optional[TextIO] = None) -> int:
    try:
        return _run(args, out or sys.stdout)
    except BrokenPipeError:           # `fap demo | head`: the reader left, not an error
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())   # no second error when Python flushes
        return 0


def _run(args: argparse.Namespace, out: TextIO) -> int:
    from .. import Master, Slave
    from ..vbus import VirtualBus

    tr = Transcript(out)
    baud = args.baud
    paced = baud if args.paced else None
    tr.plain(f"FAP demo: 1 master + {len(SLAVE_IDS)} slaves on a virtual RS-485 bus "
             f"({baud} baud, {'paced' if paced else 'unpaced'}), libfap C engines via fap_py")
    with VirtualBus(ports=1 + len(SLAVE_IDS), baud=paced) as bus:
        roles = ["master (ID 0)"] + [f"slave {i}" for i in SLAVE_IDS]
        for path, role in zip(bus.paths, roles):
            tr.plain(f"  {path:<34} {role}")
        tr.plain()
        # On a paced bus a busy machine can stall the relay thread for more than
        # FAP's 10 ms inter-byte gap in the middle of a 1024-byte frame: allow 100 ms.
        gap = dict(byte_gap=0.1) if paced else {}
        timing = dict(DEMO_TIMING)
        if paced:   # a slave's turn may carry a 1024-byte frame: allow its wire time
            timing["data_done_timeout"] += 2 * (15 + 1024) * 10 / baud
        slaves: List[Slave] = []
        master: Optional[Master] = None
        try:
            # slaves first: they answer the master's very first ID cycle
            for p, i in zip(bus.paths[1:], SLAVE_IDS):
                slaves.append(Slave(p, baud, id=i, **gap))
            master = Master(bus.paths[0], baud, slaves=SLAVE_IDS, **timing, **gap)
            return _script(tr, master, slaves, bus.paths, baud)
        finally:
            for s in slaves:
                s.close()
            if master is not None:
                master.close()


def _script(tr: Transcript, master: "Master", slaves: List["Slave"], paths: List[str],
            baud: int) -> int:
    from .. import EventKind, FapError, Slave

    tr.line("master", f"lists slaves {', '.join(map(str, SLAVE_IDS))}; ID cycle every "
            f"{DEMO_TIMING['id_cycle'] * 1000:.0f} ms (demo timing)")
    master.wait_active(timeout=WAIT_S)
    for ev in master.events():
        if ev.kind is EventKind.SLAVE_ACTIVE:
            tr.line("master", f"event: slave {ev.id} answered QUERY_ID -> active")
    tr.line("master", f"active slaves: {master.active_slaves}")

    def deliver(sender: "Node", to: int, data: bytes, receiver: "Node") -> None:
        tr.line(_name(sender.id), f"-> {_name(to):<8} {_show(data)}")
        sender.send(data, to)
        msg = receiver.recv(timeout=WAIT_S)
        ok = (msg.source, msg.data) == (sender.id, data)
        tr.line(_name(receiver.id), f"<- {_name(msg.source):<8} {_show(msg.data)} "
                f"[{'ok' if ok else 'MISMATCH'}]")
        if not ok:
            raise FapError(f"{_name(receiver.id)} got {msg!r}, expected {data!r} "
                           f"from {_name(sender.id)}")

    by_id = {s.id: s for s in slaves}
    a, b, c = (by_id[i] for i in SLAVE_IDS)
    deliver(master, a.id, b"hello slave 3", a)
    deliver(a, 0, b"temperature=21.5C", master)
    deliver(master, b.id, b"set relay 2 on", b)
    deliver(b, 0, b"relay 2 is on", master)
    deliver(c, a.id, b"slave-to-slave works too", a)
    deliver(master, c.id, bytes(range(256)) * 4, c)
    deliver(c, 0, bytes(reversed(range(256))) * 4, master)

    tr.line(_name(b.id), "leaves the bus (port closed)")
    b.close()
    while True:
        ev = master.wait_event(timeout=WAIT_S)
        if ev.kind is EventKind.SLAVE_INACTIVE and ev.id == b.id:
            break
    tr.line("master", f"event: slave {b.id} missed DATA_DONE -> inactive; "
            f"active slaves: {master.active_slaves}")
    idx = slaves.index(b)
    b = slaves[idx] = Slave(paths[1 + idx], baud, id=b.id)
    tr.line(_name(b.id), "comes back on the same port")
    master.wait_active([b.id], timeout=WAIT_S)
    tr.line("master", f"event: slave {b.id} answered QUERY_ID -> active; "
            f"active slaves: {master.active_slaves}")
    deliver(b, 0, b"I am back", master)
    deliver(master, b.id, b"welcome back", b)

    tr.plain()
    nodes = [("master", master)] + [(_name(s.id), s) for s in slaves]
    cols = ("frames_tx", "frames_rx", "data_tx", "data_rx", "polls", "cycles", "id_cycles",
            "crc_errors", "data_done_timeouts")
    heads = ("frames tx", "frames rx", "DATA tx", "DATA rx", "polls", "cycles", "ID cycles",
             "CRC err", "DONE t/o")
    tr.plain(f"{'':<9}" + "".join(f"{h:>10}" for h in heads))
    for label, node in nodes:
        st = node.stats()
        tr.plain(f"{label:<9}" + "".join(f"{getattr(st, k):>10}" for k in cols))
    tr.plain()
    tr.line("demo", f"done: {len(slaves)} slaves active {master.active_slaves}, "
            f"RS-485 mode {master.rs485_mode.name} (a pty has no RS-485 ioctls)")
    return 0
