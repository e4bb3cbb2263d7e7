"""``fap toy request``: one request to a toy slave, its reply printed; the toy's CLI plug-in,
written only against fap_py.commands' shared helpers and the protocol table."""
from __future__ import annotations

import argparse

from fap_py import _protocols
from fap_py.commands._node import show
from fap_py.commands._options import (
    add_actions,
    add_command,
    add_output_options,
    add_port_options,
    emit,
    hexbytes,
    integer,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = _protocols.get("toy")
    cmd = add_command(sub, "toy", help="toy protocol (tests only): a request to a slave",
                      example="fap toy request --port /dev/pts/3 --node 2 0102")
    r = add_command(add_actions(cmd, "toy_command"), "request", help="send one request, print the reply",
                    example="fap toy request --port /dev/pts/3 --node 2 0102")
    add_port_options(r, baud_default=p.default_baud)
    add_output_options(r)
    r.add_argument("--node", type=integer, required=True, help=f"slave node {p.node_min}..{p.node_max}")
    r.add_argument("--timeout", metavar="S", type=float, default=0.5, help="reply timeout, seconds")
    r.add_argument("data", type=hexbytes, help="request payload, hex")
    r.set_defaults(func=run_request)


def run_request(args: argparse.Namespace) -> int:
    from toyproto.binding import Master

    with Master(args.port, args.baud, timeout=args.timeout) as m:
        reply = m.request(args.node, args.data)
    emit(args, {"event": "reply", "node": args.node, "data": reply}, f"node {args.node}: {show(reply)}")
    return 0
