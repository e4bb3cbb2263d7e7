"""``fap demo``: a running FAP bus in the terminal, no hardware.

A :class:`~fap_py.vbus.VirtualBus` gives 1 + N pty ports wired as one
RS-485 bus; a :class:`~fap_py.Master` and N :class:`~fap_py.Slave` objects
(each a libfap C engine) exchange messages both ways for ``--duration``
seconds. On a terminal a live view (rich) shows per-node state and
counters, goodput against the wire's capacity, recent messages and events,
updated in place; otherwise plain lines and a summary. ``--faults`` puts
bit errors on the bus and silences one slave for a while, so CRC errors,
inactive marking and recovery show. Ctrl-C ends it with the summary.

Every number is an engine counter (``fapx_get_stats`` through
:meth:`~fap_py.fap.Node.stats`). Goodput is the DATA frames the engines
delivered (``data_rx``) times the demo's fixed payload size
(:data:`PAYLOAD`), per second; capacity is baud / 10 bytes per second.
"""
from __future__ import annotations

import argparse
import collections
import random
import sys
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Deque, Dict, List, Optional, Tuple

from .. import _protocols
from ..rs485 import DEFAULT_BAUD
from ._node import CLIENT, long_running
from ._options import EXIT_INTERRUPTED, add_command, add_output_options, baud, emit, seconds

if TYPE_CHECKING:  # pragma: no cover
    from ..fap import Master, Slave

PAYLOAD = 32                 #: bytes in every demo message (goodput = data_rx x PAYLOAD)
SLAVE_IDS = (3, 7, 12, 18, 21, 25, 29, _protocols.get("fap").node_max)   # the top ID too
TICK = 0.02                  #: seconds between traffic rounds
# Protocol timing shortened for the demo (vendor defaults: 15 s, 1 s, 15 s).
DEMO_TIMING = {"id_cycle": 0.2, "id_answer_timeout": 0.1, "data_done_timeout": 0.5}
TTY_DURATION, PLAIN_DURATION = 10.0, 3.0
BER = 0.00005              #: --faults: per-byte probability of a flipped bit


def register(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    p = add_command(
        sub, "demo", help="a live FAP bus (master + slaves on a virtual bus) in this terminal",
        description="Create a virtual RS-485 bus, run a FAP master and --slaves slaves "
        "(libfap's C engines through fap_py) on it in this process and let them exchange "
        "messages. On a terminal: a live view of node states, counters, goodput, messages and "
        "events; otherwise plain lines and a summary. Ctrl-C ends it with the summary. "
        "No hardware.",
        example="fap demo\nfap demo --faults --duration 20\nfap demo --paced --baud 38400 "
        "--slaves 5\nfap demo --json | tail -1")
    p.add_argument("--duration", metavar="S", type=seconds, default=None,
                   help=f"how long to run, seconds (default: {TTY_DURATION:g} on a terminal, "
                   f"{PLAIN_DURATION:g} otherwise)")
    p.add_argument("--slaves", metavar="N", type=int, choices=range(1, len(SLAVE_IDS) + 1),
                   default=3, help=f"number of slaves, 1..{len(SLAVE_IDS)}")
    p.add_argument("--baud", metavar="N", type=baud, default=DEFAULT_BAUD,
                   help="line speed the nodes configure")
    p.add_argument("--paced", action="store_true",
                   help="the virtual bus delivers bytes at --baud (10 bits/byte) like a real "
                   "wire; default: as fast as the ptys go")
    p.add_argument("--faults", action="store_true",
                   help="bit errors on the bus, and one slave silenced for a while: CRC errors, "
                   "inactive marking and recovery show")
    p.add_argument("--seed", type=int, default=1, help="seed of traffic and faults")
    p.add_argument("--plain", action="store_true", help="plain lines even on a terminal")
    add_output_options(p)
    long_running(p, CLIENT, run)     # SIGTERM ends it like Ctrl-C: summary, exit 130


@dataclass
class View:
    """What the screen shows, refreshed from the engines."""

    t0: float
    baud: int
    paced: bool
    ids: List[int]
    nodes: List[Tuple[str, Any]] = field(default_factory=list)
    stats: Dict[str, Any] = field(default_factory=dict)
    active: List[int] = field(default_factory=list)
    messages: Deque[str] = field(default_factory=lambda: collections.deque(maxlen=6))
    events: Deque[str] = field(default_factory=lambda: collections.deque(maxlen=8))
    fault: str = ""
    last_elapsed: float = 0.0

    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def refresh(self, master: "Master") -> None:
        self.stats = {label: node.stats for label, node in self.nodes}
        self.active = master.active_slaves
        self.last_elapsed = self.elapsed()

    def totals(self) -> Dict[str, float]:
        """Bus-wide numbers from the engine counters."""
        el = max(self.last_elapsed, 1e-6)
        wire_bytes = sum(st.bytes_tx for st in self.stats.values())   # each byte has one sender
        delivered = sum(st.data_rx for st in self.stats.values())
        cap = self.baud / 10.0
        return dict(seconds=round(el, 3), wire_bytes=wire_bytes, data_frames=delivered,
                    goodput=delivered * PAYLOAD / el, capacity=cap,
                    crc_errors=sum(st.crc_errors for st in self.stats.values()),
                    utilisation=wire_bytes / el / cap)


def _stamp(view: View) -> str:
    return f"{view.elapsed():6.2f}s"


def _label(i: int) -> str:
    return "master" if i == 0 else f"slave {i}"


def run(args: argparse.Namespace) -> int:
    tty = sys.stdout.isatty() and not args.json and not args.plain
    if args.duration is None:
        args.duration = TTY_DURATION if tty else PLAIN_DURATION
    try:
        return _run(args, tty)
    except BrokenPipeError:
        raise
    except KeyboardInterrupt:   # already summarised inside
        return EXIT_INTERRUPTED


def _run(args: argparse.Namespace, tty: bool) -> int:
    from .. import Master, Slave
    from ..errors import QueueFullError
    from ..vbus import VirtualBus

    ids = list(SLAVE_IDS[:args.slaves])
    rng = random.Random(args.seed)
    paced = args.baud if args.paced else None
    with VirtualBus(ports=1 + len(ids), baud=paced, seed=args.seed) as bus:
        gap = dict(byte_gap=0.1) if paced else {}    # a loaded machine may stall the relay
        timing = dict(DEMO_TIMING)
        if paced:   # a turn may carry a few frames at wire speed
            timing["data_done_timeout"] += 8 * (15 + PAYLOAD) * 10 / args.baud
        slaves: List[Slave] = []
        master: Optional[Master] = None
        try:
            for p, i in zip(bus.paths[1:], ids):
                slaves.append(Slave(p, args.baud, id=i, **gap))
            master = Master(bus.paths[0], args.baud, slaves=ids, **timing, **gap)
            view = View(time.monotonic(), args.baud, bool(paced), ids)
            view.nodes = [("master", master)] + [(_label(s.id), s) for s in slaves]
            out = _Live(view, args) if tty else _Plain(view, args)
            interrupted = False
            with out:
                try:
                    _traffic(args, bus, master, slaves, view, out, rng, QueueFullError)
                except KeyboardInterrupt:
                    interrupted = True
                view.refresh(master)
            _summary(args, view, master, interrupted)
            return EXIT_INTERRUPTED if interrupted else 0
        finally:
            for s in slaves:
                s.close()
            if master is not None:
                master.close()


def _traffic(args: argparse.Namespace, bus: Any, master: "Master", slaves: List["Slave"],
             view: View, out: Any, rng: random.Random, full: type) -> None:
    """Send, receive and show until --duration is over."""
    from ..fap import EventKind

    if args.faults:
        bus.set_fault(None, bit_error_rate=BER)
    victim = slaves[-1]
    silence_at, silence_for, silenced = args.duration * 0.3, min(2.0, args.duration * 0.25), False
    n = 0
    end = view.t0 + args.duration
    next_draw = 0.0
    while True:
        now = time.monotonic()
        if now >= end:
            break
        if silenced and view.fault and now - view.t0 >= silence_at + silence_for:
            out.event({"event": "fault_over", "slave": victim.id},
                      f"{_stamp(view)} fault over: slave {victim.id} talks again")
            view.fault = ""
        if args.faults and not silenced and now - view.t0 >= silence_at:
            bus.silence(1 + slaves.index(victim), silence_for)
            silenced = True
            view.fault = f"slave {victim.id} silenced for {silence_for:.1f} s"
            out.event({"event": "fault", "slave": victim.id, "silenced_s": silence_for,
                       "bit_error_rate": BER},
                      f"{_stamp(view)} fault: {view.fault} (bus bit error rate {BER:.2%} per byte)")
        n += 1
        for s in slaves:
            if rng.random() < 0.5:
                _send(s, 0, f"slave {s.id:02d} reading {n:06d} t={20 + rng.random() * 5:4.1f}C",
                      full)
        active = master.active_slaves
        if active and rng.random() < 0.7:
            to = rng.choice(active)
            _send(master, to, f"master -> {to:02d} setpoint {n:06d}", full)
        for label, node in view.nodes:
            while True:
                msg = node.recv_nowait()
                if msg is None:
                    break
                view.messages.append(f"{_stamp(view)} {_label(msg.source):>8} -> {label:<8} "
                                     f"{msg.data.decode(errors='replace').rstrip()}")
        for ev in master.events():
            text = {EventKind.SLAVE_ACTIVE: "active (answered QUERY_ID)",
                    EventKind.SLAVE_INACTIVE: "inactive (missed DATA_DONE)",
                    EventKind.ID_TIMEOUT: "did not answer QUERY_ID"}.get(
                        ev.kind, ev.kind.name.lower())
            out.event({"event": ev.kind.name.lower(), "slave": ev.id},
                      f"{_stamp(view)} slave {ev.id} {text}")
        if now >= next_draw:
            view.refresh(master)
            out.update()
            next_draw = now + (0.25 if out.live else 1.0)
        time.sleep(TICK)   # pacing of the traffic generator, not synchronisation


def _send(node: Any, to: int, text: str, full: "type[BaseException]") -> None:
    data = text.encode().ljust(PAYLOAD)[:PAYLOAD]
    try:
        node.send(data, to, timeout=0)
    except full:
        pass   # the bus is slower than the generator: skip this one


class _Plain:
    """No terminal: events as lines, a status line a second."""

    live = False

    def __init__(self, view: View, args: argparse.Namespace) -> None:
        self.view, self.args = view, args

    def __enter__(self) -> "_Plain":
        v = self.view
        emit(self.args, {"event": "start", "slaves": v.ids, "baud": v.baud, "paced": v.paced,
                         "duration": self.args.duration, "faults": self.args.faults},
             f"FAP demo: master + slaves {', '.join(map(str, v.ids))} on a virtual RS-485 bus "
             f"({v.baud} baud, {'paced' if v.paced else 'unpaced'}"
             f"{', faults' if self.args.faults else ''}), {self.args.duration:g} s")
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def event(self, obj: Dict[str, Any], text: str) -> None:
        emit(self.args, {**obj, "t": round(self.view.elapsed(), 3)}, text)

    def update(self) -> None:
        t = self.view.totals()
        emit(self.args, {"event": "status", "active": self.view.active, **t},
             f"{t['seconds']:6.2f}s active {', '.join(map(str, self.view.active)) or 'none'} "
             f"on the {'' if self.view.paced else 'unpaced '}wire "
             f"{t['wire_bytes']} B, DATA delivered {t['data_frames']}, CRC errors "
             f"{t['crc_errors']}, goodput {t['goodput']:.0f} B/s")


class _Live:
    """A terminal: a rich Live view updated in place."""

    live = True

    def __init__(self, view: View, args: argparse.Namespace) -> None:
        from rich.console import Console
        from rich.live import Live

        self.view, self.args = view, args
        self.console = Console()
        self._live = Live(self._render(), console=self.console, refresh_per_second=8,
                          transient=False)

    def __enter__(self) -> "_Live":
        self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self._live.update(self._render())
        self._live.__exit__(None, None, None)

    def event(self, obj: Dict[str, Any], text: str) -> None:
        self.view.events.append(text)

    def update(self) -> None:
        self._live.update(self._render())

    def _render(self) -> Any:
        from rich.console import Group
        from rich.panel import Panel
        from rich.table import Table

        v = self.view
        t = v.totals() if v.stats else None
        table = Table(expand=False, box=None, padding=(0, 1), header_style="bold")
        for col in ("node", "state", "frames tx", "frames rx", "bytes tx", "bytes rx",
                    "DATA tx", "DATA rx", "CRC err", "polls"):
            table.add_column(col, justify="left" if col in ("node", "state") else "right")
        for label, node in v.nodes:
            st = v.stats.get(label)
            if node.id == 0:
                state = "[cyan]polling[/]"
            else:
                state = "[green]active[/]" if node.id in v.active else "[red]inactive[/]"
            nums = ("-",) * 8 if st is None else (
                st.frames_tx, st.frames_rx, st.bytes_tx, st.bytes_rx, st.data_tx, st.data_rx,
                st.crc_errors, st.polls)
            table.add_row(label, state, *map(str, nums))
        mode = f"{v.baud} baud, {'paced' if v.paced else 'unpaced (ptys run faster than the baud)'}"
        head = (f"[bold]FAP demo[/] {mode} - {v.elapsed():5.1f} / {self.args.duration:g} s - "
                "Ctrl-C ends")
        if t:
            line = (f"goodput [bold]{t['goodput']:.0f} B/s[/] of {t['capacity']:.0f} B/s wire "
                    f"capacity ({t['goodput'] / t['capacity']:.0%}); "
                    + (f"bus load {t['utilisation']:.0%}; " if v.paced else
                       f"{t['wire_bytes'] / t['seconds']:.0f} B/s on the unpaced wire; ")
                    + f"CRC errors {t['crc_errors']}")
        else:
            line = "starting..."
        if v.fault:
            line += f"; [yellow]{v.fault}[/]"
        msgs = "\n".join(v.messages) or "(none yet)"
        evs = "\n".join(v.events) or "(none yet)"
        return Group(Panel(Group(head, table, line), title="nodes (engine counters)"),
                     Panel(msgs, title="recent messages"), Panel(evs, title="events"))


def _summary(args: argparse.Namespace, view: View, master: "Master", interrupted: bool) -> None:
    t = view.totals()
    rows = {label: st.as_dict() for label, st in view.stats.items()}
    emit(args, {"event": "summary", "interrupted": interrupted, "active": view.active,
                "nodes": rows, **t}, None)
    if args.json:
        return
    print()
    ids = ", ".join(map(str, view.ids))
    active = ", ".join(map(str, view.active)) or "none"
    print(f"summary after {t['seconds']:.1f} s{' (interrupted)' if interrupted else ''}: "
          f"active slaves {active} (of {ids})")
    cols = ("frames_tx", "frames_rx", "bytes_tx", "bytes_rx", "data_tx", "data_rx",
            "crc_errors", "id_cycles", "data_done_timeouts")
    heads = ("frames tx", "frames rx", "bytes tx", "bytes rx", "DATA tx", "DATA rx",
             "CRC err", "ID cycles", "DONE t/o")
    print(f"{'':<9}" + "".join(f"{h:>10}" for h in heads))
    for label, st in view.stats.items():
        print(f"{label:<9}" + "".join(f"{getattr(st, k):>10}" for k in cols))
    # short lines (each under 80 columns): a terminal would wrap a long one inside a word
    print(f"goodput {t['goodput']:.0f} B/s ({t['data_frames']} DATA frames x {PAYLOAD} B); "
          f"wire capacity {t['capacity']:.0f} B/s at {view.baud} baud")
    if not view.paced:
        print("  unpaced bus: the ptys deliver faster than the baud, so these figures can "
              "exceed\n  the capacity (--paced holds the bus to the baud)")
    print(f"{t['wire_bytes']} bytes on the {'' if view.paced else 'unpaced '}wire; RS-485 mode "
          f"{master.rs485_mode.name.lower()} (a pty has no RS-485 ioctls)", flush=True)
