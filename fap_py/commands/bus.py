"""``fap bus``: run a virtual RS-485 bus until SIGINT/SIGTERM.

Prints one line per port (``port<i> <path>``) and then ``ready`` on stdout,
flushed, so a script can wait for the paths; on exit prints the counters.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
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


class _Status:
    """On a terminal: one status line on stderr, rewritten in place twice a
    second: bytes/s written by the nodes and delivered, totals, and every
    error counter of the bus (``fap_vbus_stats``, bus-wide: the C API has
    no per-port counters and the bus knows bytes, not frames)."""

    PERIOD = 0.5

    def __init__(self, bus: "VirtualBus") -> None:
        self.bus = bus
        self.last = bus.stats()
        self.t = time.monotonic()
        self.width = 0

    def show(self) -> None:
        now = time.monotonic()
        if now - self.t < self.PERIOD:
            return
        st, dt = self.bus.stats(), now - self.t
        rate_in = (st.bytes_in - self.last.bytes_in) / dt
        rate_out = (st.bytes_out - self.last.bytes_out) / dt
        self.last, self.t = st, now
        line = (f"bus: in {rate_in:,.0f} B/s, out {rate_out:,.0f} B/s; total in "
                f"{st.bytes_in:,} B, out {st.bytes_out:,} B; errors: collisions "
                f"{st.collisions}, bit errors {st.bit_errors}, dropped {st.dropped}, "
                f"overflow {st.overflow}, disconnects {st.disconnects}")
        sys.stderr.write("\r" + line.ljust(self.width))
        sys.stderr.flush()
        self.width = len(line)

    def end(self) -> None:
        if self.width:
            sys.stderr.write("\n")
            sys.stderr.flush()


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
            status = _Status(bus) if sys.stderr.isatty() and not args.json else None
            while not stop.wait(0.2):   # signal handlers run between waits
                if status is not None:
                    status.show()
            if status is not None:
                status.end()
            st = bus.stats()
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    keys = ("bytes_in", "bytes_out", "collisions", "bit_errors", "dropped", "overflow",
            "disconnects")
    emit(args, {"event": "stats", **{k: getattr(st, k) for k in keys}},
         "stats " + " ".join(f"{k}={getattr(st, k)}" for k in keys))
    return 0
