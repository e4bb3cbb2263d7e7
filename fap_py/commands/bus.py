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
from typing import TYPE_CHECKING, Any, List, Optional

from ._options import add_command, add_output_options, add_realtime_option, baud, emit

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
    p.add_argument("--ber", type=probability, default=0.0, metavar="X",
                   help="per-byte probability of one flipped bit, every port")
    p.add_argument("--drop-rate", type=probability, default=0.0, metavar="X",
                   help="per-byte probability of a dropped byte, every port")
    p.add_argument("--seed", type=int, default=0, help="seed of the random faults")
    add_realtime_option(p)   # the relay thread (docs/realtime.md)
    add_output_options(p)
    p.set_defaults(func=run)


def probability(text: str) -> float:
    """argparse type of ``--ber`` / ``--drop-rate``: a probability, 0..1."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability in 0..1, not {text!r}")
    return v


def _open(args: argparse.Namespace) -> "VirtualBus":
    """The bus, with an error that names the file or directory at fault
    (the C layer reports one code for both)."""
    from ..vbus import LinkDirBusyError, VirtualBus

    if args.capture:
        try:
            with open(args.capture, "ab"):
                pass
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write the --capture file ({exc.strerror})",
                          args.capture) from None
    try:
        return VirtualBus(ports=args.ports, baud=args.baud or None, echo=args.echo,
                          link_dir=args.link_dir, capture=args.capture, seed=args.seed,
                          realtime=args.realtime)
    except LinkDirBusyError as exc:   # exit 3, as a port another program holds
        who = f"pid {exc.pid}" if exc.pid is not None else "another process"
        exc.strerror = (f"{args.link_dir}: --link-dir: another fap bus ({who}) is running on it; stop it "
                        "or use another directory")
        raise
    except OSError as exc:
        if not args.link_dir or exc.errno is None:
            raise
        raise OSError(exc.errno, f"cannot use --link-dir ({os.strerror(exc.errno)})",
                      args.link_dir) from None


class _CaptureTail:
    """Per-port counts read from the bus's own ``--capture`` file as it grows
    (docs/vbus.md: one data line per transmission, paced, or per chunk the
    relay read, unpaced; ``collision``/``fault``/``overflow`` event lines),
    at most :attr:`CHUNK` bytes a call so a fast bus cannot stall the view.
    The complete lines are parsed by :func:`fap_py.vbus.iter_capture`, the
    format's one parser; a line still being written waits for the next call."""

    CHUNK = 1 << 20
    #: the events that count as a port's errors, and the field naming the port(s)
    ERROR_EVENTS = ("collision", "fault", "overflow")

    def __init__(self, path: str, ports: int) -> None:
        self.file = open(path, "rb")
        self.rest = b""
        self.tx = [0] * ports          #: data lines (transmissions) sent by each port
        self.bytes = [0] * ports       #: bytes sent by each port
        self.errors = [0] * ports      #: collision, fault and overflow events of each port

    def close(self) -> None:
        self.file.close()

    def poll(self) -> None:
        from ..vbus import CaptureEvent, CaptureRecord, iter_capture

        data = self.file.read(self.CHUNK)
        if not data:
            return
        *lines, self.rest = (self.rest + data).split(b"\n")
        for item in iter_capture(line.decode("ascii", "replace") for line in lines):
            if isinstance(item, CaptureRecord) and item.port < len(self.tx):
                self.tx[item.port] += 1
                self.bytes[item.port] += len(item.data)
            elif isinstance(item, CaptureEvent) and item.kind in self.ERROR_EVENTS:
                for port in (item.fields.get("ports") or item.fields.get("port") or "").split(","):
                    if port.isdigit() and int(port) < len(self.errors):
                        self.errors[int(port)] += 1


class _Status:
    """On a terminal: a status view on stderr, redrawn in place twice a
    second (rich): bytes/s written by the nodes and delivered, totals and
    every error counter of the bus (``fap_vbus_stats``); with ``--capture``
    also one row per port (transmissions/s, bytes/s, bytes, errors) read
    from the capture, since the bus counts bytes, not frames or ports."""

    PERIOD = 0.5

    def __init__(self, bus: "VirtualBus", capture: Optional[str]) -> None:
        from rich.console import Console
        from rich.live import Live

        self.bus = bus
        self.last = bus.stats
        self.t = time.monotonic()
        self.tail = _CaptureTail(capture, len(bus.paths)) if capture else None
        self.prev = ([0] * len(bus.paths), [0] * len(bus.paths))
        self.live = Live(console=Console(stderr=True, highlight=False), auto_refresh=False,
                         transient=True)
        self.live.start()

    def show(self) -> None:
        now = time.monotonic()
        if now - self.t < self.PERIOD:
            return
        from rich.console import Group
        from rich.table import Table

        st, dt = self.bus.stats, now - self.t
        rate_in = (st.bytes_in - self.last.bytes_in) / dt
        rate_out = (st.bytes_out - self.last.bytes_out) / dt
        self.last, self.t = st, now
        parts: List[Any] = [
            f"bus: in {rate_in:,.0f} B/s, out {rate_out:,.0f} B/s; total in {st.bytes_in:,} B, "
            f"out {st.bytes_out:,} B; errors: collisions {st.collisions}, bit errors "
            f"{st.bit_errors}, dropped {st.dropped}, overflow {st.overflow}, disconnects "
            f"{st.disconnects}"]
        if self.tail is None:
            parts.append("(per-port rows with --capture)")
        else:
            self.tail.poll()
            table = Table(box=None, padding=(0, 1))
            for col in ("port", "tx/s", "B/s", "bytes", "errors"):
                table.add_column(col, justify="left" if col == "port" else "right")
            tx0, b0 = self.prev
            for i in range(len(self.tail.tx)):
                table.add_row(f"port{i}", f"{(self.tail.tx[i] - tx0[i]) / dt:,.0f}",
                              f"{(self.tail.bytes[i] - b0[i]) / dt:,.0f}",
                              f"{self.tail.bytes[i]:,}", str(self.tail.errors[i]))
            self.prev = (list(self.tail.tx), list(self.tail.bytes))
            parts.append(table)
        self.live.update(Group(*parts), refresh=True)

    def end(self) -> None:
        self.live.stop()
        if self.tail is not None:
            self.tail.close()


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
            status = _Status(bus, args.capture) if sys.stderr.isatty() and not args.json \
                else None
            try:
                while not stop.wait(0.2):   # signal handlers run between waits
                    if status is not None:
                        status.show()
            finally:
                if status is not None:
                    status.end()
            st = bus.stats
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    keys = ("bytes_in", "bytes_out", "collisions", "bit_errors", "dropped", "overflow",
            "disconnects")
    emit(args, {"event": "stats", **{k: getattr(st, k) for k in keys}},
         "stats " + " ".join(f"{k}={getattr(st, k)}" for k in keys))
    return 0
