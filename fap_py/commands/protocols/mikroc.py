"""``fap mikroc master|slave``: mikroC RS-485 (3-byte messages) on a port.

    fap mikroc master --port /dev/ttyUSB0 --address 5 010203 --count 0 --interval 0.5
    fap mikroc slave --port /dev/ttyUSB1 --address 5 --reply echo
"""
from __future__ import annotations

import argparse
from dataclasses import asdict
from typing import TYPE_CHECKING

from fap_py import _protocols

from .. import _options as opt
from .._node import (
    CLIENT,
    SERVER,
    Payloads,
    add_payload_options,
    long_running,
    reply_option,
    show,
    stop_on_sigterm,
)

if TYPE_CHECKING:  # pragma: no cover
    from fap_py.mikroc import NodeStats

PROTOCOL = _protocols.get("mikroc")   # broadcast address: from the binding


def register(sub: argparse._SubParsersAction) -> None:
    p = opt.add_command(sub, "mikroc", help="mikroC RS-485: master requests, a slave that answers",
                        example="fap mikroc master --port /dev/ttyUSB0 --address 5 010203")
    cmds = opt.add_actions(p, "mikroc_command")

    m = opt.add_command(cmds, "master", help="send 0..3 bytes to a slave and print its reply",
                        example="fap mikroc master --port /dev/ttyUSB0 --address 5 010203 --count 0 "
                        f"--interval 0.5\nfap mikroc master --port /dev/ttyUSB0 --address {PROTOCOL.broadcast} 01   "
                        "# broadcast, no reply")
    opt.add_echo_option(opt.add_port_options(m, baud_default=PROTOCOL.default_baud))
    opt.add_link_options(m, timeout_default=0.2, retries_default=0)
    opt.add_output_options(m)
    m.add_argument("--address", type=opt.integer, required=True, help=f"slave address ({PROTOCOL.broadcast} = broadcast)")
    opt.add_repeat_options(m)
    add_payload_options(m, what="message", size=" (0..3 bytes each)")
    long_running(m, CLIENT, run_master)

    s = opt.add_command(cmds, "slave", help="answer as a slave until interrupted",
                        example="fap mikroc slave --port /dev/ttyUSB1 --address 5 --reply echo")
    opt.add_echo_option(opt.add_port_options(s, baud_default=PROTOCOL.default_baud))
    opt.add_output_options(s)
    s.add_argument("--address", type=opt.integer, required=True, help="this slave's address")
    s.add_argument("--reply", type=reply_option(3), default="echo", help="'echo', 'none' or a fixed reply in hex (0..3 bytes)")
    s.add_argument("--max-requests", type=opt.integer, default=0, help="stop after N (0 = never)")
    long_running(s, SERVER, run_slave)


def run_master(args: argparse.Namespace) -> int:
    from fap_py.errors import FapTimeoutError, FrameError
    from fap_py.mikroc import BROADCAST, MAX_DATA, Master

    def check(req: bytes) -> None:      # a line over 3 bytes is skipped, not the batch's end
        if len(req) > MAX_DATA:
            raise opt.UsageError(f"a mikroC message is 0..{MAX_DATA} bytes, not {len(req)}")

    data = Payloads(args, check=check)
    failed = sent = 0
    interrupted = False
    with Master(args.port, args.baud, rs485=opt.rs485_from_args(args)) as master:
        try:
            for batch in data.passes():
                for req in batch:
                    if args.address == BROADCAST:
                        master.send(args.address, req)
                        opt.emit(args, {"event": "broadcast", "data": req}, f"broadcast: {show(req)}")
                        continue
                    sent += 1
                    for attempt in range(args.retries + 1):
                        try:
                            reply = master.request(args.address, req, timeout=args.timeout)
                        except (FapTimeoutError, FrameError) as exc:
                            if attempt < args.retries:
                                continue
                            failed += 1
                            opt.emit(args, {"event": "error", "address": args.address,
                                        "error": str(exc)}, f"slave {args.address}: {exc}")
                        else:
                            opt.emit(args, {"event": "reply", "address": reply.address,
                                        "data": reply.data},
                                     f"slave {reply.address}: {show(reply.data)}")
                        break
        except KeyboardInterrupt:       # Ctrl-C: the summary, then exit 130
            interrupted = True
        _stats(args, master.stats, interrupted)
    if interrupted:
        return opt.EXIT_INTERRUPTED
    data.finish(f"{failed} of {opt.plural(sent, 'request')} to slave {args.address} got no valid "
                "reply" if failed else "")
    return 0


def _stats(args: argparse.Namespace, st: "NodeStats", interrupted: bool = False) -> None:
    opt.emit(args, {"event": "stats", **asdict(st), **({"interrupted": True} if interrupted else {})},
             f"{opt.plural(st.frames, 'frame')}, {opt.plural(st.errors, 'error')}, {st.damaged} damaged, "
             f"{st.ignored} ignored" + (" (interrupted)" if interrupted else ""))


def run_slave(args: argparse.Namespace) -> int:
    from fap_py.errors import ClosedError, FapTimeoutError, FrameError
    from fap_py.mikroc import BROADCAST, Slave

    fixed = None if args.reply in ("echo", "none") else opt.hexbytes(args.reply)
    with Slave(args.port, args.baud, args.address, rs485=opt.rs485_from_args(args)) as slave, \
            stop_on_sigterm() as done:
        opt.emit(args, {"event": "ready", "address": args.address, "port": args.port,
                    "baud": args.baud},
                 f"ready: mikroC slave {args.address} on {args.port} at {args.baud} baud "
                 f"(reply: {args.reply})")
        served = 0
        while not done.is_set() and (not args.max_requests or served < args.max_requests):
            try:
                msg = slave.receive(timeout=0.2)
            except FapTimeoutError:
                continue
            except FrameError as exc:
                opt.emit(args, {"event": "bad_frame", "error": str(exc)}, f"bad frame: {exc}")
                continue
            except ClosedError:
                break
            served += 1
            opt.emit(args, {"event": "request", "address": msg.address, "data": msg.data},
                     f"{'broadcast' if msg.address == BROADCAST else 'request'}: {show(msg.data)}")
            if args.reply != "none" and msg.address != BROADCAST:
                slave.send(msg.data if fixed is None else fixed)
        _stats(args, slave.stats)
    return 0
