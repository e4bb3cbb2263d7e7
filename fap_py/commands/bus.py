"""``fap bus``: run a virtual RS-485 bus until SIGINT/SIGTERM.

Prints one line per port (``port<i> <path>``) and then ``ready`` on stdout,
flushed, so a script can wait for the paths; on exit prints the counters.
"""
from __future__ import annotations

import argparse
import os
import signal
import threading
from typing import TYPE_CHECKING

from ._options import add_command, add_output_options, baud, emit

if TYPE_CHECKING:  # pragma: no cover
    from ..vbus import VirtualBus


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(
        sub, "bus", help="run a virtual multi-drop RS-485 bus of pseudo-terminals",
        description="Create N pty ports that behave as one 2-wire RS-485 bus: every byte "
        "written on one port reaches every other port. Runs until SIGINT/SIGTERM.",
        example="fap bus --ports 4 --link-dir /tmp/bus --baud 115200")
    p.add_argument("--ports", type=int, default=3, help="number of ports, 2..64")
    p.add_argument("--baud", metavar="N", type=baud, default=None,
                   help="pace delivery at 10 bits/byte and detect collisions (default: unpaced)")
    p.add_argument("--echo", action="store_true", help="deliver each byte back to its sender too")
    p.add_argument("--link-dir", metavar="DIR",
                   help="directory for the stable symlinks port0..portN-1 (default: a temp dir)")
    p.add_argument("--capture", metavar="FILE", help="record every byte on the bus (docs/vbus.md)")
    p.add_argument("--ber", type=float, default=0.0, metavar="X",
                   help="per-byte probability of one flipped bit, every port")
    p.add_argument("--drop-rate", type=float, default=0.0, metavar="X",
                   help="per-byte probability of a dropped byte, every port")
    p.add_argument("--seed", type=int, default=0, help="seed of the random faults")
    add_output_options(p)
    p.set_defaults(func=run)


def _open(args: argparse.Namespace) -> "VirtualBus":
    """The bus, with an error that names the file or directory at fault
    (the C layer reports one code for both)."""
    from ..vbus import VirtualBus

    if args.capture:
        try:
            with open(args.capture, "ab"):
                pass
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write the --capture file ({exc.strerror})",
                          args.capture) from None
    try:
        return VirtualBus(ports=args.ports, baud=args.baud or None, echo=args.echo,
                          link_dir=args.link_dir, capture=args.capture, seed=args.seed)
    except OSError as exc:
        if not args.link_dir or exc.errno is None:
            raise
        raise OSError(exc.errno, f"cannot use --link-dir ({os.strerror(exc.errno)})",
                      args.link_dir) from None


def run(args: argparse.Namespace) -> int:

    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with _open(args) as bus:
            if args.ber or args.drop_rate:
                bus.set_fault(None, bit_error_rate=args.ber, drop_rate=args.drop_rate)
            for i, path in enumerate(bus.paths):
                emit(args, {"event": "port", "index": i, "path": path}, f"port{i} {path}")
            mode = f"{args.baud} baud" if args.baud else "unpaced"
            emit(args, {"event": "ready", "ports": len(bus.paths), "baud": args.baud,
                        "echo": args.echo},
                 f"ready ({len(bus.paths)} ports, {mode}{', echo' if args.echo else ''})")
            while not stop.wait(0.2):   # signal handlers run between waits
                pass
            st = bus.stats()
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    keys = ("bytes_in", "bytes_out", "collisions", "bit_errors", "dropped", "overflow",
            "disconnects")
    emit(args, {"event": "stats", **{k: getattr(st, k) for k in keys}},
         "stats " + " ".join(f"{k}={getattr(st, k)}" for k in keys))
    return 0
