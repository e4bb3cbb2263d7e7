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
from typing import Any, List

from fap_py import _protocols

from .. import _options as opt
from .._node import Payloads, Stop, add_payload_options, show, stop_on_sigterm

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
                       help="longest wait for the bus to come up (master: a listed slave "
                       "active; slave: polled by the master) before sending")
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
    m.set_defaults(func=run_master)

    s = opt.add_command(cmds, "slave", help="run a slave: send when polled, print what arrives",
                        example="fap fap slave --port /dev/ttyUSB1 --id 3 --count 0\n"
                        "echo 'temp=21.5' | fap fap slave --port /dev/ttyUSB1 --id 3 --text -")
    common(s)
    s.add_argument("--id", type=opt.integer, required=True, help=f"this slave's ID, {PROTOCOL.node_min}..{PROTOCOL.node_max}")
    s.add_argument("--to", type=opt.integer, default=0, help="destination of DATA (0 = master)")
    s.set_defaults(func=run_slave)


def _print_message(args: argparse.Namespace, msg: Any) -> None:
    src = "master" if msg.source == 0 else f"slave {msg.source}"
    opt.emit(args, {"event": "rx", "from": msg.source, "data": msg.data},
             f"<- {src}: {show(msg.data)}")


def _print_events(args: argparse.Namespace, node: Any) -> None:
    for ev in node.events():
        opt.emit(args, {"event": ev.kind.name.lower(), "slave": ev.id},
                 f"event: slave {ev.id} {ev.kind.name.lower().replace('slave_', '')}")


def _loop(args: argparse.Namespace, node: Any, to: int, data: Payloads, is_master: bool,
          done: Stop) -> int:
    """Send, then collect for --interval; --count times (0 = until ``done``,
    set by a signal). Returns the exit code: 130 when Ctrl-C ended a master,
    else 0."""
    from fap_py.errors import FapTimeoutError

    sent = 0
    i = 0
    data.stop = done          # Ctrl-C only sets `done`: a stdin wait must see it
    while not done.is_set() and (args.count == 0 or i < args.count):
        for d in data:
            node.send(d, to, timeout=args.wait)
            sent += 1
            dst = "master" if to == 0 else f"slave {to}"
            opt.emit(args, {"event": "tx", "to": to, "data": d}, f"-> {dst}: {show(d)}")
            if done.is_set():
                break
        end = time.monotonic() + args.interval
        while not done.is_set():
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
    if sent and not done.is_set():
        try:
            node.flush(timeout=args.wait)
        except FapTimeoutError:
            left = node.tx_pending
            opt.emit(args, {"event": "unsent", "frames": left},
                     f"{opt.plural(left, 'message')} still queued (not polled within {args.wait} s)")
    st = node.stats
    opt.emit(args, {"event": "stats", **st.as_dict(),
                **({"interrupted": True} if done.interrupted else {})},
             f"frames tx {st.frames_tx} rx {st.frames_rx}, DATA tx {st.data_tx} rx {st.data_rx}, "
             f"CRC errors {st.crc_errors}" + (" (interrupted)" if done.interrupted else ""))
    data.finish()
    # a master polling is a client: Ctrl-C is an interruption (130); a slave
    # with --count 0 is a server, whose normal end is a signal (docs/cli.md)
    return opt.EXIT_INTERRUPTED if done.interrupted and is_master else 0


def run_master(args: argparse.Namespace) -> int:
    from fap_py import Master
    from fap_py.errors import FapTimeoutError

    to = args.to if args.to is not None else args.slaves[0]
    if to not in args.slaves:
        raise opt.UsageError(f"--to {to} is not one of --slaves {args.slaves}")
    data = Payloads(args, empty=False)
    with Master(args.port, args.baud, slaves=args.slaves, id_cycle=args.id_cycle,
                id_answer_timeout=args.id_answer_timeout, rs485=opt.rs485_from_args(args)) as master, \
            stop_on_sigterm() as done:
        opt.emit(args, {"event": "ready", "port": args.port, "baud": args.baud, "slaves": args.slaves,
                    "rs485": master.rs485_mode},
                 f"ready: FAP master on {args.port} at {args.baud} baud, slaves "
                 f"{', '.join(map(str, args.slaves))} (RS-485 {master.rs485_mode.name})")
        if args.data:
            try:
                master.wait_active([to], timeout=args.wait)
            except FapTimeoutError:
                raise opt.BusError(f"slave {to} did not answer the ID query within {args.wait} s") \
                    from None
        _print_events(args, master)
        return _loop(args, master, to, data, True, done)


def run_slave(args: argparse.Namespace) -> int:
    from fap_py import Slave

    data = Payloads(args, empty=False)
    with Slave(args.port, args.baud, id=args.id, rs485=opt.rs485_from_args(args)) as slave, \
            stop_on_sigterm() as done:
        opt.emit(args, {"event": "ready", "port": args.port, "baud": args.baud, "id": args.id,
                    "rs485": slave.rs485_mode},
                 f"ready: FAP slave {args.id} on {args.port} at {args.baud} baud "
                 f"(RS-485 {slave.rs485_mode.name})")
        return _loop(args, slave, args.to, data, False, done)
