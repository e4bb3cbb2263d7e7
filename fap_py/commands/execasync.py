"""``fap exec``: exec async frames, master polls and a slave, from the shell.

    fap exec encode --node 5 --seq 1 414243
    fap exec decode 100205014142431003b9ec
    fap exec poll --port /dev/ttyUSB0 --node 5 0102 --count 3
    fap exec broadcast --port /dev/ttyUSB0 ff00
    fap exec slave --port /dev/ttyUSB0 --node 5 --reply echo
"""
from __future__ import annotations

import argparse
import signal
import threading


def _int(text: str) -> int:
    return int(text, 0)


def _hex(text: str) -> bytes:
    try:
        return bytes.fromhex(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"not hex bytes: {text!r}") from exc


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("exec", help="exec async protocol: encode/decode, master polls, a slave")
    cmds = p.add_subparsers(dest="exec_command", metavar="ACTION", required=True)

    e = cmds.add_parser("encode", help="print the frame for node, seq and data")
    e.add_argument("--node", type=_int, required=True)
    e.add_argument("--seq", type=_int, default=0)
    e.add_argument("data", type=_hex, nargs="?", default=b"", help="payload, hex")
    e.set_defaults(func=run_encode)

    d = cmds.add_parser("decode", help="decode frames from hex bytes")
    d.add_argument("data", type=_hex, help="received bytes, hex")
    d.set_defaults(func=run_decode)

    def line(q: argparse.ArgumentParser) -> None:
        q.add_argument("--port", required=True, help="serial device path")
        q.add_argument("--baud", type=int, default=115200)
        q.add_argument("--rs485-mode", choices=["auto", "kernel", "soft_rts", "none"],
                       default="auto")
        q.add_argument("--echo-suppression", action="store_true",
                       help="read back and drop our own bytes (2-wire adapters)")

    m = cmds.add_parser("poll", help="poll a node and print its replies")
    line(m)
    m.add_argument("--node", type=_int, required=True, help="1..254")
    m.add_argument("--timeout", type=float, default=0.1, help="per attempt, seconds")
    m.add_argument("--retries", type=int, default=3)
    m.add_argument("--count", type=int, default=1)
    m.add_argument("data", type=_hex, nargs="?", default=b"", help="payload, hex")
    m.set_defaults(func=run_poll)

    b = cmds.add_parser("broadcast", help="send to every slave (node 255)")
    line(b)
    b.add_argument("data", type=_hex, nargs="?", default=b"", help="payload, hex")
    b.set_defaults(func=run_broadcast)

    s = cmds.add_parser("slave", help="answer as a node until interrupted")
    line(s)
    s.add_argument("--node", type=_int, required=True, help="1..254")
    s.add_argument("--reply", default="echo",
                   help="'echo' (default), 'none' or a fixed reply in hex")
    s.add_argument("--turnaround-us", type=int, default=0,
                   help="quiet time before each reply, microseconds")
    s.add_argument("--max-requests", type=int, default=0, help="stop after N (0 = never)")
    s.set_defaults(func=run_slave)


def _rs485(args: argparse.Namespace, turnaround_us: int = 0):
    from fap_py.execasync import RS485, RS485Mode

    return RS485(mode=RS485Mode[args.rs485_mode.upper()],
                 echo_suppression=bool(args.echo_suppression), turnaround_us=turnaround_us)


def run_encode(args: argparse.Namespace) -> int:
    from fap_py.execasync import encode

    print(encode(args.node, args.data, args.seq).hex())
    return 0


def run_decode(args: argparse.Namespace) -> int:
    from fap_py.execasync import Decoder

    frames = Decoder().feed(args.data)
    for f in frames:
        print(f"node {f.node} seq {f.seq} {f.status.name} data {f.data.hex()}")
    return 0 if frames and all(f.ok for f in frames) else 1


def run_poll(args: argparse.Namespace) -> int:
    from fap_py.execasync import ExecAsyncError, Master

    failed = 0
    with Master(args.port, args.baud, timeout=args.timeout, retries=args.retries,
                rs485=_rs485(args)) as master:
        for _ in range(args.count):
            seq = master.next_seq(args.node)
            try:
                reply = master.transact(args.node, args.data)
                print(f"node {args.node} seq {seq}: {reply.hex()}")
            except ExecAsyncError as exc:
                failed += 1
                print(f"node {args.node} seq {seq}: {exc}")
        st = master.stats
        print(f"{st.transactions} transactions, {st.retries} retries, {st.failures} failed, "
              f"{st.corrupt} corrupt frames")
    return 1 if failed else 0


def run_broadcast(args: argparse.Namespace) -> int:
    from fap_py.execasync import Master

    with Master(args.port, args.baud, rs485=_rs485(args)) as master:
        master.broadcast(args.data)
    return 0


def run_slave(args: argparse.Namespace) -> int:
    from fap_py.errors import ClosedError
    from fap_py.execasync import Request, Slave

    fixed = None if args.reply in ("echo", "none") else _hex(args.reply)

    def handler(req: Request):
        kind = "broadcast" if req.broadcast else f"seq {req.seq}"
        print(f"{kind}: {req.data.hex()}", flush=True)
        if args.reply == "none":
            return None
        return req.data if fixed is None else fixed

    with Slave(args.port, args.baud, node=args.node, handler=handler,
               rs485=_rs485(args, args.turnaround_us)) as slave:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: slave.stop())
        served = 0
        try:
            while not args.max_requests or served < args.max_requests:
                # slices: Python runs signal handlers (Ctrl-C) between them
                served += slave.serve(0.2) != 0
        except (ClosedError, KeyboardInterrupt):
            pass
        st = slave.stats
        print(f"processed {st.processed}, resent {st.resent}, broadcasts {st.broadcasts}, "
              f"corrupt {st.corrupt}, ignored {st.ignored}")
    return 0
