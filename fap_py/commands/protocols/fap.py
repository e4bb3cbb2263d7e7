"""``fap fap master|slave``: a FAP node (libfap's C engine) on a port.

Sends each payload (arguments or stdin lines) to ``--to``, then prints the
messages that arrive during ``--interval``; ``--count`` repeats (0 = until
Ctrl-C). The master also prints slave events (active/inactive).

    fap fap master --port /dev/ttyUSB0 --slaves 3,7 --to 3 68656c6c6f
    fap fap slave --port /dev/ttyUSB1 --id 3 --count 0
"""
from __future__ import annotations

import argparse
import time
from collections import deque
from typing import Any, Deque, Dict, List, Tuple

from fap_py import _protocols
from fap_py.errors import QueueFullError

from .. import _options as opt
from .._node import (
    CLIENT,
    SERVER,
    Payloads,
    Stop,
    add_payload_options,
    handles_signals,
    long_running,
    show,
    stop_on_sigterm,
)

PROTOCOL = _protocols.get("fap")   # its facts (slave IDs, default baud) come from the binding


def _ids(text: str) -> List[int]:
    try:
        ids = [int(x, 0) for x in text.replace(",", " ").split()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a list of IDs: {text!r}") from None
    lo, hi = PROTOCOL.node_min, PROTOCOL.node_max
    if not ids or any(not lo <= i <= hi for i in ids):
        raise argparse.ArgumentTypeError(f"slave IDs are {lo}..{hi}: {text!r}")
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        raise argparse.ArgumentTypeError(
            f"slave ID{'s' if len(twice) > 1 else ''} {', '.join(map(str, twice))} listed twice: "
            f"{text!r}")
    return ids


def register(sub: argparse._SubParsersAction) -> None:
    p = opt.add_command(sub, "fap", help="FAP (libfap) master or slave on a port",
                        example="fap fap master --port /dev/ttyUSB0 --slaves 3,7 --to 3 68656c6c6f")
    cmds = opt.add_actions(p, "fap_command")

    def common(q: argparse.ArgumentParser) -> None:
        opt.add_echo_option(opt.add_port_options(q, baud_default=PROTOCOL.default_baud))
        opt.add_output_options(q)
        opt.add_repeat_options(q)
        q.add_argument("--wait", metavar="S", type=opt.seconds, default=5.0,
                       help="longest wait for the bus to come up (master: the destination "
                       "slave active) and, at the end, for what is queued to be sent (slave: "
                       "polled by the master)")
        q.add_argument("--max-age", metavar="S", type=opt.seconds, default=None,
                       help="drop (and count) a queued message not sent within S seconds "
                       "(default: 10 x --interval, at least twice --wait)")
        add_payload_options(q)

    m = opt.add_command(cmds, "master", help="run the master (ID 0): poll slaves, send, print what arrives",
                        example="fap fap master --port /dev/ttyUSB0 --slaves 3,7 --to 3 68656c6c6f\n"
                        "fap fap master --port /dev/ttyUSB0 --slaves 3 --count 0 --json   # listen")
    common(m)
    m.add_argument("--slaves", type=_ids, required=True, metavar="IDS",
                   help="slave IDs to poll, e.g. 3,7,12")
    m.add_argument("--to", type=opt.integer, help="destination slave of DATA (default: the first of --slaves)")
    # None: the C engine's defaults (fapx_options, as the vendor's fapInit)
    m.add_argument("--id-cycle", metavar="S", type=opt.seconds, default=None,
                   help="seconds between ID cycles while a slave is inactive (default: the "
                   "API's and vendor's, 15)")
    m.add_argument("--id-answer-timeout", metavar="S", type=opt.seconds, default=None,
                   help="how long the master waits for a slave's ID after QUERY_ID (default: "
                   "the API's, 1); shorter makes an absent slave cost less polling time")
    long_running(m, CLIENT, run_master)

    s = opt.add_command(cmds, "slave", help="run a slave: send when polled, print what arrives",
                        example="fap fap slave --port /dev/ttyUSB1 --id 3 --count 0\n"
                        "echo 'temp=21.5' | fap fap slave --port /dev/ttyUSB1 --id 3 --text -")
    common(s)
    s.add_argument("--id", type=opt.integer, required=True, help=f"this slave's ID, {PROTOCOL.node_min}..{PROTOCOL.node_max}")
    s.add_argument("--to", type=opt.integer, default=0, help="destination of DATA (0 = master)")
    long_running(s, SERVER, run_slave)


def _print_message(args: argparse.Namespace, msg: Any) -> None:
    src = "master" if msg.source == 0 else f"slave {msg.source}"
    opt.emit(args, {"event": "rx", "from": msg.source, "data": msg.data},
             f"<- {src}: {show(msg.data)}")


def _print_events(args: argparse.Namespace, node: Any) -> None:
    for ev in node.events():
        opt.emit(args, {"event": ev.kind.name.lower(), "slave": ev.id},
                 f"event: slave {ev.id} {ev.kind.name.lower().replace('slave_', '')}")


#: messages the command holds for the engine at most (the engine's own queue, FAPX_DEFAULT_TX_DEPTH)
BACKLOG = 64
#: a slave counts as polled while its last poll is at most this old (s), or two --interval
PRESENCE_S = 2.0
#: the skipped/stale notes: the first at once, then at most one per this many seconds
NOTE_EVERY_S = 1.0


class Outbox:
    """What a FAP command sends, between its payloads and the engine's transmit queue.

    A message is *queued* when the command takes it (``tx`` event: ``-> master: ...
    (queued)``) and *sent* when the engine puts it on the wire, the master having polled
    the slave (a slave) or in the master's turn (``sent`` event). The command hands
    messages to the engine only while the peer is there (a slave: polled within
    :data:`PRESENCE_S`; the master: the destination slave active), so a returning peer
    never gets a backlog older than ``--max-age``: older messages are dropped, counted
    and said (``stale``). The backlog is bounded (:data:`BACKLOG`): a message that finds
    it full while the peer is away is skipped, counted and said (``skipped``); while the
    peer is there the command waits for room.
    """

    def __init__(self, args: argparse.Namespace, node: Any, to: int, is_master: bool,
                 done: Stop) -> None:
        self.args, self.node, self.to, self.is_master, self.done = args, node, to, is_master, done
        self.max_age = args.max_age if args.max_age is not None \
            else max(10 * args.interval, 2 * args.wait)
        self.waiting: Deque[Tuple[float, bytes]] = deque()   # not handed to the engine yet
        self.engine: Deque[bytes] = deque()    # handed to the engine, not on the wire yet
        self.queued = self.sent = self.stale = self.skipped = 0
        self._polls = -1
        self._polled_at = -1e9
        self._window = max(PRESENCE_S, 2 * args.interval)
        self._said: Dict[str, float] = {}
        self._unsaid_skips = self._unsaid_stale = 0

    def _dst(self) -> str:
        return "master" if self.to == 0 else f"slave {self.to}"

    def present(self) -> bool:
        """Whether the peer is there: the destination active (master), polled lately (slave)."""
        if self.is_master:
            return self.to in self.node.active_slaves
        polls = self.node.stats.polls
        now = time.monotonic()
        if polls != self._polls:
            if self._polls >= 0:
                self._polled_at = now
            self._polls = polls
        return now - self._polled_at <= self._window

    def pending(self) -> int:
        return len(self.waiting) + len(self.engine)

    def add(self, data: bytes) -> None:
        self.pump()
        if len(self.waiting) >= BACKLOG:
            end = time.monotonic() + self.args.wait
            while len(self.waiting) >= BACKLOG and self.present() and not self.done.is_set() \
                    and time.monotonic() < end:
                self.done.wait(0.02)        # the engine drains while the peer polls
                self.pump()
            if len(self.waiting) >= BACKLOG:
                self.skipped += 1
                self._unsaid_skips += 1
                self._say_skips()
                return
        self.waiting.append((time.monotonic(), data))
        self.queued += 1
        opt.emit(self.args, {"event": "tx", "to": self.to, "data": data},
                 f"-> {self._dst()}: {show(data)} (queued)")
        self.pump()

    def pump(self) -> None:
        """Report what went on the wire, drop what got stale, hand the engine what it
        can take while the peer is there."""
        node = self.node
        for _ in range(max(0, len(self.engine) - node.tx_pending)):
            data = self.engine.popleft()
            self.sent += 1
            opt.emit(self.args, {"event": "sent", "to": self.to, "data": data},
                     f"-> {self._dst()}: {show(data)} (sent)")
        now = time.monotonic()
        dropped = 0
        while self.waiting and now - self.waiting[0][0] > self.max_age:
            self.waiting.popleft()
            dropped += 1
        if dropped:
            self.stale += dropped
            self._unsaid_stale += dropped
        self._say_stale()
        self._say_skips()
        there = self.present()      # every pump: a poll is seen when it happens
        if self.waiting and there:
            while self.waiting:
                try:
                    node.send(self.waiting[0][1], self.to)
                except QueueFullError:
                    break
                self.engine.append(self.waiting.popleft()[1])

    # the notes: at once for the first, then at most one a second (with the totals)
    def _due(self, kind: str, force: bool) -> bool:
        now = time.monotonic()
        if force or now - self._said.get(kind, -1e9) >= NOTE_EVERY_S:
            self._said[kind] = now
            return True
        return False

    def _say_skips(self, force: bool = False) -> None:
        if self._unsaid_skips and self._due("skipped", force):
            n, self._unsaid_skips = self._unsaid_skips, 0
            _note(self.args, {"event": "skipped", "to": self.to, "skipped": n,
                              "total": self.skipped, "backlog": BACKLOG},
                  f"{BACKLOG} messages already wait for the {self._dst()} ("
                  f"{'not active' if self.is_master else 'not polling'}): "
                  f"{opt.plural(n, 'message')} skipped ({self.skipped} so far)")

    def _say_stale(self, force: bool = False) -> None:
        if self._unsaid_stale and self._due("stale", force):
            n, self._unsaid_stale = self._unsaid_stale, 0
            _note(self.args, {"event": "stale", "to": self.to, "dropped": n,
                              "total": self.stale, "max_age": self.max_age},
                  f"{opt.plural(n, 'message')} dropped: not sent within --max-age "
                  f"{self.max_age:g} s ({self.stale} so far)")

    def drain(self, timeout: float) -> None:
        """Pump until everything is on the wire, ``timeout`` passed or a signal came."""
        end = time.monotonic() + timeout
        while self.pending() and not self.done.is_set() and time.monotonic() < end:
            self.done.wait(0.02)
            self.pump()

    def finish(self) -> None:
        """The last report of what went out, and the notes not said yet."""
        self.pump()
        self._say_stale(True)
        self._say_skips(True)

    def counts(self) -> Dict[str, int]:
        return {"queued": self.queued, "sent": self.sent, "stale": self.stale,
                "skipped": self.skipped, "unsent": self.pending()}


def _note(args: argparse.Namespace, obj: Dict[str, Any], text: str) -> None:
    from .._node import note
    note(args, obj, text)


def _loop(args: argparse.Namespace, node: Any, to: int, data: Payloads, is_master: bool,
          done: Stop) -> int:
    """Queue the payloads, then collect for --interval; --count times (0 = until
    ``done``, set by SIGINT or SIGTERM). Returns the exit code: 130 when a signal
    ended a master, 0 for a slave (a server); exit 1 (BusError) when messages were
    still not sent at the end of a run no signal cut short."""
    from fap_py.errors import FapTimeoutError

    out = Outbox(args, node, to, is_master, done)

    def idle() -> None:        # while a stdin line is awaited: keep the outbox and rx going
        out.pump()
        msg = node.recv_nowait()
        while msg is not None:
            _print_message(args, msg)
            msg = node.recv_nowait()
        if is_master:
            _print_events(args, node)

    i = 0
    data.stop = done          # a signal only sets `done`: a stdin wait must see it
    data.idle = idle
    while not done.is_set() and (args.count == 0 or i < args.count):
        for d in data:
            out.add(d)
            if done.is_set():
                break
        end = time.monotonic() + args.interval
        while not done.is_set():
            out.pump()
            left = end - time.monotonic()
            if left <= 0:
                break
            try:
                _print_message(args, node.recv(timeout=min(left, 0.2)))
            except FapTimeoutError:
                pass
            if is_master:
                _print_events(args, node)
        i += 1
    if not done.is_set():
        out.drain(args.wait)
    out.finish()
    counts = out.counts()
    unsent = counts["unsent"]
    if unsent and not done.is_set():
        opt.emit(args, {"event": "unsent", "messages": unsent, "wait": args.wait},
                 f"{opt.plural(unsent, 'message')} not sent: the {out._dst()} "
                 f"{'was not active' if is_master else 'did not poll'} within {args.wait:g} s")
    st = node.stats
    signalled = done.is_set()
    opt.emit(args, {"event": "stats", **st.as_dict(), "messages": counts,
                    **({"interrupted": True} if signalled and is_master else {})},
             f"frames tx {st.frames_tx} rx {st.frames_rx}, DATA tx {st.data_tx} rx {st.data_rx}, "
             f"CRC errors {st.crc_errors}; messages queued {counts['queued']}, sent "
             f"{counts['sent']}, stale {counts['stale']}, skipped {counts['skipped']}, unsent "
             f"{unsent}" + (" (interrupted)" if signalled and is_master else ""))
    # a master polling is a client: a signal is an interruption (130); a slave is a
    # server, whose normal end is a signal (docs/cli.md)
    if signalled:
        data.finish()
        return opt.EXIT_INTERRUPTED if is_master else 0
    lost = counts["stale"] + counts["skipped"] + unsent
    data.finish(f"{opt.plural(lost, 'message')} of {counts['queued'] + counts['skipped']} "
                f"not sent ({counts['stale']} stale, {counts['skipped']} skipped, {unsent} "
                f"unsent within --wait {args.wait:g} s)" if lost else "")
    return 0


def _check_payload(data: bytes) -> None:
    from fap_py.fap import MAX_DATA

    if not 1 <= len(data) <= MAX_DATA:
        raise opt.UsageError(f"a FAP message is 1..{MAX_DATA} bytes, not {len(data)}")


@handles_signals
def run_master(args: argparse.Namespace) -> int:
    from fap_py import Master
    from fap_py.errors import FapTimeoutError

    to = args.to if args.to is not None else args.slaves[0]
    if to not in args.slaves:
        raise opt.UsageError(f"--to {to} is not one of --slaves {args.slaves}")
    data = Payloads(args, empty=False, check=_check_payload)
    with Master(args.port, args.baud, slaves=args.slaves, id_cycle=args.id_cycle,
                id_answer_timeout=args.id_answer_timeout, rs485=opt.rs485_from_args(args)) as master, \
            stop_on_sigterm() as done:
        opt.emit(args, {"event": "ready", "port": args.port, "baud": args.baud, "slaves": args.slaves,
                    "rs485": master.rs485_mode},
                 f"ready: FAP master on {args.port} at {args.baud} baud, slaves "
                 f"{', '.join(map(str, args.slaves))} (RS-485 {master.rs485_mode.name})")
        if args.data:
            # in slices: SIGINT/SIGTERM only set `done`, the wait must end on them
            end = time.monotonic() + args.wait
            while not done.is_set():
                try:
                    master.wait_active([to], timeout=max(0.0, min(0.1, end - time.monotonic())))
                    break
                except FapTimeoutError:
                    if time.monotonic() >= end:
                        _print_events(args, master)
                        raise opt.BusError(f"slave {to} did not answer the ID query within "
                                           f"{args.wait:g} s") from None
        _print_events(args, master)
        return _loop(args, master, to, data, True, done)


def run_slave(args: argparse.Namespace) -> int:
    from fap_py import Slave

    data = Payloads(args, empty=False, check=_check_payload)
    with Slave(args.port, args.baud, id=args.id, rs485=opt.rs485_from_args(args)) as slave, \
            stop_on_sigterm() as done:
        opt.emit(args, {"event": "ready", "port": args.port, "baud": args.baud, "id": args.id,
                    "rs485": slave.rs485_mode},
                 f"ready: FAP slave {args.id} on {args.port} at {args.baud} baud "
                 f"(RS-485 {slave.rs485_mode.name})")
        return _loop(args, slave, args.to, data, False, done)
