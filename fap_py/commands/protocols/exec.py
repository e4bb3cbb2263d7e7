"""``fap exec``: exec async frames, a master, a slave and a node scan.

    fap exec encode --node 5 --seq 1 414243
    fap exec decode 100205014142431003b9ec
    fap exec master --port /dev/ttyUSB0 --node 5 0102 --count 3
    fap exec master --port /dev/ttyUSB0 --node 255 ff00          # broadcast
    fap exec slave --port /dev/ttyUSB0 --node 5 --reply echo
    fap exec scan --port /dev/ttyUSB0 --first 1 --last 32
"""
from __future__ import annotations

import argparse
from dataclasses import asdict

from fap_py import _protocols

from .. import _options as opt
from .._node import (
    CLIENT,
    SERVER,
    Payloads,
    add_payload_options,
    long_running,
    reply_option,
    scan,
    scan_summary,
    show,
    stop_on_sigterm,
)

PROTOCOL = _protocols.get("exec")   # node range, broadcast node, default baud: from the binding


def _nodes() -> str:
    return f"{PROTOCOL.node_min}..{PROTOCOL.node_max}"


def register(sub: argparse._SubParsersAction) -> None:
    p = opt.add_command(sub, "exec", help="exec async protocol: master, slave, scan, encode/decode",
                        example="fap exec master --port /dev/ttyUSB0 --node 5 0102")
    cmds = opt.add_actions(p, "exec_command")

    e = opt.add_command(cmds, "encode", help="print the frame for node, seq and data",
                        example="fap exec encode --node 5 --seq 1 414243")
    e.add_argument("--node", type=opt.integer, required=True, help=f"{_nodes()}, {PROTOCOL.broadcast} = broadcast")
    e.add_argument("--seq", type=opt.integer, default=0, help="sequence number 0..255")
    e.add_argument("data", type=opt.hexbytes, nargs="?", default=b"",
                   help="payload, hex (default: empty)")
    opt.add_output_options(e)
    e.set_defaults(func=run_encode)

    d = opt.add_command(cmds, "decode", help="decode frames from hex bytes (exit 1 if any is bad "
                        "or the input ends inside a frame)",
                        example="fap exec decode 100205014142431003b9ec")
    d.add_argument("data", type=opt.hexbytes, help="received bytes, hex")
    opt.add_output_options(d)
    d.set_defaults(func=run_decode)

    def line(q: argparse.ArgumentParser) -> None:
        opt.add_echo_option(opt.add_port_options(q, baud_default=PROTOCOL.default_baud))
        opt.add_output_options(q)

    m = opt.add_command(cmds, "master", aliases=["poll"],
                        help="send requests to a node and print its replies",
                        example="fap exec master --port /dev/ttyUSB0 --node 5 0102 --count 0 "
                        "--interval 0.5\necho 0102 | fap exec master --port /dev/ttyUSB0 --node 5 --json -")
    line(m)
    opt.add_link_options(m, timeout_default=0.1, retries_default=3)
    m.add_argument("--node", type=opt.integer, required=True, help=f"{_nodes()}, {PROTOCOL.broadcast} = broadcast (no reply)")
    opt.add_repeat_options(m)
    add_payload_options(m, what="request")
    long_running(m, CLIENT, run_master)

    b = opt.add_command(cmds, "broadcast", help=f"send to every slave (node {PROTOCOL.broadcast}), no reply",
                        example="fap exec broadcast --port /dev/ttyUSB0 ff00")
    line(b)
    add_payload_options(b)
    long_running(b, CLIENT, run_broadcast)   # '-': until stdin ends

    s = opt.add_command(cmds, "slave", help="answer as a node until interrupted",
                        example="fap exec slave --port /dev/ttyUSB0 --node 5 --reply echo")
    line(s)
    s.add_argument("--node", type=opt.integer, required=True, help=_nodes())
    s.add_argument("--reply", type=reply_option(), default="echo",
                   help="'echo', 'none' or a fixed reply in hex")
    s.add_argument("--turnaround-us", type=opt.integer, default=0,
                   help="quiet time before each reply, microseconds")
    s.add_argument("--max-requests", type=opt.integer, default=0, help="stop after N (0 = never)")
    long_running(s, SERVER, run_slave)

    c = opt.add_command(cmds, "scan", help="find the nodes that answer (progress bar on a terminal)",
                        example="fap exec scan --port /dev/ttyUSB0 --first 1 --last 32 --timeout 0.05")
    line(c)
    opt.add_link_options(c, timeout_default=0.05, retries_default=0)
    c.add_argument("--first", type=opt.integer, default=PROTOCOL.node_min, help="first node to try")
    c.add_argument("--last", type=opt.integer, default=PROTOCOL.node_max, help="last node to try")
    c.add_argument("--probe", metavar="HEX", type=opt.hexbytes, default=b"",
                   help="request payload sent to each node, hex (default: empty)")
    long_running(c, CLIENT, run_scan)


def _rs485(args: argparse.Namespace, turnaround_us: int = 0):
    return opt.rs485_from_args(args, turnaround_us=turnaround_us)


def _size_check(most: int):
    """Payloads' check: a request over ``most`` bytes is a bad payload (a stdin line
    is reported and skipped), not a failed request."""
    def check(req: bytes) -> None:
        if len(req) > most:
            raise opt.UsageError(f"an exec async request is 0..{most} bytes, not {len(req)}")
    return check


def run_encode(args: argparse.Namespace) -> int:
    from fap_py.execasync import encode

    frame = encode(args.node, args.data, args.seq)
    opt.emit(args, {"event": "encoded", "frame": frame, "node": args.node, "seq": args.seq, "data": args.data}, frame.hex())
    return 0


def run_decode(args: argparse.Namespace) -> int:
    from fap_py.execasync import MAX_FRAME, Decoder

    dec = Decoder()
    frames = dec.feed(args.data)
    for f in frames:
        opt.emit(args, {"event": "frame", "node": f.node, "seq": f.seq, "status": f.status, "data": f.data},
                 f"node {f.node} seq {f.seq} {f.status.name} data {f.data.hex()}")
    # what the decoder still holds after the last complete frame: a truncated frame
    tail = _unfinished(args.data, frames)
    if tail:
        opt.emit(args, {"event": "truncated", "status": "truncated", "bytes": tail},
                 f"truncated frame: {opt.plural(len(tail), 'byte')} after the last complete frame "
                 f"({tail.hex()}), input ends inside a frame (max frame {MAX_FRAME} bytes)")
    if not frames and not tail:
        opt.emit(args, {"event": "no_frame", "status": "no_frame", "bytes": args.data},
                 f"no exec async frame in {opt.plural(len(args.data), 'byte')}")
    return 0 if frames and not tail and all(f.ok for f in frames) else 1


def _unfinished(data: bytes, frames: list) -> bytes:
    """Bytes after the last frame the decoder completed that start a frame
    (DLE STX ...): they were cut off."""
    from fap_py.execasync import Decoder, encode

    # The decoder reports only complete frames; find where the last one ended
    # by re-feeding prefixes (inputs are command-line sized).
    if not data:
        return b""
    end = 0
    if frames:
        dec = Decoder()
        seen = 0
        for i in range(len(data)):
            seen += len(dec.feed(data[i:i + 1]))
            if seen == len(frames):
                end = i + 1
                break
    rest = data[end:]
    start_marker = encode(1)[:2]    # DLE STX: what every frame starts with
    k = rest.find(start_marker)
    return rest[k:] if k >= 0 else b""


def run_master(args: argparse.Namespace) -> int:
    from fap_py.execasync import BROADCAST, MAX_DATA, ExecAsyncError, Master

    data = Payloads(args, check=_size_check(MAX_DATA))
    failed = sent = 0
    interrupted = False
    with Master(args.port, args.baud, timeout=args.timeout, retries=args.retries,
                rs485=_rs485(args)) as master:
        try:
            for batch in data.passes():
                for req in batch:
                    if args.node == BROADCAST:
                        master.broadcast(req)
                        opt.emit(args, {"event": "broadcast", "data": req}, f"broadcast: {show(req)}")
                        continue
                    seq = master.next_seq(args.node)
                    sent += 1
                    try:
                        reply = master.transact(args.node, req)
                        opt.emit(args, {"event": "reply", "node": args.node, "seq": seq,
                                    "data": reply}, f"node {args.node} seq {seq}: {show(reply)}")
                    except ExecAsyncError as exc:
                        failed += 1
                        why = opt.detail(exc, f"node {args.node}")
                        opt.emit(args, {"event": "error", "node": args.node, "seq": seq,
                                    "error": why}, f"node {args.node} seq {seq}: {why}")
        except KeyboardInterrupt:       # Ctrl-C: the summary, then exit 130
            interrupted = True
        st = master.stats
        opt.emit(args, {"event": "stats", **asdict(st), "interrupted": interrupted},
                 f"{opt.plural(st.transactions, 'transaction')}, {opt.plural(st.retries, 'retry', 'retries')}"
                 f", {st.failures} failed, {opt.plural(st.corrupt, 'corrupt frame')}"
                 + (" (interrupted)" if interrupted else ""))
    if interrupted:
        return opt.EXIT_INTERRUPTED
    data.finish(f"{failed} of {opt.plural(sent, 'request')} to node {args.node} failed"
                if failed else "")
    return 0


def run_broadcast(args: argparse.Namespace) -> int:
    from fap_py.execasync import MAX_DATA, Master

    data = Payloads(args, check=_size_check(MAX_DATA))
    sent = 0
    with Master(args.port, args.baud, rs485=_rs485(args)) as master:
        try:
            for req in data:
                master.broadcast(req)
                sent += 1
                opt.emit(args, {"event": "broadcast", "data": req}, f"broadcast: {show(req)}")
        except KeyboardInterrupt:       # Ctrl-C or SIGTERM while stdin is read: the summary
            opt.emit(args, {"event": "summary", "broadcasts": sent, "interrupted": True},
                     f"{opt.plural(sent, 'broadcast')} sent (interrupted)")
            return opt.EXIT_INTERRUPTED
    data.finish()
    return 0


def run_slave(args: argparse.Namespace) -> int:
    from fap_py.errors import ClosedError
    from fap_py.execasync import Request, Slave

    fixed = None if args.reply in ("echo", "none") else opt.hexbytes(args.reply)

    def handler(req: Request):
        kind = "broadcast" if req.broadcast else f"seq {req.seq}"
        opt.emit(args, {"event": "request", "node": args.node, "seq": req.seq,
                    "broadcast": req.broadcast, "data": req.data}, f"{kind}: {req.data.hex()}")
        if args.reply == "none":
            return None
        return req.data if fixed is None else fixed

    with Slave(args.port, args.baud, node=args.node, handler=handler,
               rs485=_rs485(args, args.turnaround_us)) as slave, stop_on_sigterm() as done:
        opt.emit(args, {"event": "ready", "node": args.node, "port": args.port, "baud": args.baud},
                 f"ready: exec async slave node {args.node} on {args.port} at {args.baud} baud "
                 f"(reply: {args.reply})")
        served = 0
        try:
            while not done.is_set() and (not args.max_requests or served < args.max_requests):
                # slices: Python runs signal handlers between them
                served += slave.serve(0.2) != 0
        except ClosedError:
            pass
        st = slave.stats
        opt.emit(args, {"event": "stats", **asdict(st)},
                 f"processed {st.processed}, resent {st.resent}, broadcasts {st.broadcasts}, "
                 f"corrupt {st.corrupt}, ignored {st.ignored}")
    return 0


def run_scan(args: argparse.Namespace) -> int:
    from fap_py.execasync import ExecAsyncError, Master

    lo, hi = PROTOCOL.node_min, PROTOCOL.node_max
    if not lo <= args.first <= args.last <= hi:
        from .._options import UsageError
        raise UsageError(f"need {lo} <= --first <= --last <= {hi}, not {args.first}..{args.last}")
    with Master(args.port, args.baud, timeout=args.timeout, retries=args.retries,
                rs485=_rs485(args)) as master:
        def probe(node: int):
            try:
                return master.transact(node, args.probe)
            except ExecAsyncError:
                return None

        result = scan(list(range(args.first, args.last + 1)), probe, label="exec node",
                      progress=not args.json,
                      found=lambda n, r: opt.emit(args, {"event": "found", "node": n, "reply": r},
                                                  f"node {n} answers: {show(r)}"))
    return scan_summary(args, result, args.last - args.first + 1, "nodes")
