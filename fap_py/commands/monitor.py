"""``fap monitor``: a protocol analyser for FAP, exec async, mikroC and G485.

    fap monitor --protocol fap --raw bytes.bin
    fap monitor --protocol auto --capture bus.cap --stats
    fap monitor --protocol exec --port /dev/ttyUSB0 --baud 115200 --idle 5 --json
    some-reader | fap monitor --protocol g485 --pcap out.pcap
    fap monitor --dissectors ~/.local/lib/wireshark/plugins
"""
from __future__ import annotations

import argparse
import errno
import json
import logging
import os
import signal
import sys
import threading
from typing import List, Optional

from ._options import (
    EXIT_INTERRUPTED,
    UsageError,
    add_command,
    add_output_options,
    add_port_options,
    rs485_from_args,
    seconds,
)

log = logging.getLogger(__name__)

EXAMPLE = """\
fap monitor --protocol fap --raw bytes.bin
fap monitor --protocol auto --capture bus.cap --stats
fap monitor --protocol exec --port /dev/ttyUSB0 --baud 115200 --follow --json
cat bytes.bin | fap monitor --protocol g485 --pcap out.pcap
fap monitor --dissectors ~/.local/lib/wireshark/plugins"""

DESCRIPTION = """\
A protocol analyser for FAP, exec async, mikroC and G485: reads a live port
(receive-only), a raw byte file, a virtual-bus capture or stdin; prints
frames, JSON, statistics, pcap. See docs/monitor.md.

exit: 0 input read to its end or SIGTERM (bad frames are reported, not
      failures), 2 usage error, 3 file or port error, 130 interrupted (SIGINT)"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The monitor's options: input, decoder, outputs (the shared groups included)."""
    from fap_py.monitor.decoders import PROTOCOLS

    p.add_argument("--protocol", choices=list(PROTOCOLS) + ["auto"], default="auto",
                   help="decoder; auto tries all four and reports which one locks on")
    add_port_options(p, baud_default=None, port_required=False, rs485_default="none",
                     port_help="live serial port, opened receive-only (or give --raw, --capture, "
                     "or bytes on stdin)",
                     baud_help="line rate: opens --port at it (115200 if not given); sets the "
                     "inter-byte gap and bus utilisation for the other inputs (a capture's own "
                     "rate if not given)")
    src = p.add_argument_group("other inputs (instead of --port)")
    src.add_argument("--raw", metavar="FILE", help="raw bytes as recorded from a port")
    src.add_argument("--capture", metavar="FILE",
                     help="virtual-bus capture (fap bus --capture): senders and times kept")
    p.add_argument("--follow", action="store_true",
                   help="live port: keep reading until interrupted (else stop after --idle "
                        "seconds of silence)")
    p.add_argument("--idle", type=seconds, default=2.0, metavar="S",
                   help="live port without --follow: stop after this much silence, seconds")
    add_output_options(p)
    p.add_argument("--stats", action="store_true",
                   help="print only the statistics (frames, errors per node, reply times)")
    p.add_argument("--pcap", metavar="FILE", help="also write every frame to this pcap file")
    p.add_argument("--dissectors", metavar="DIR",
                   help="write the Wireshark Lua dissector to DIR (and exit if no input given)")
    p.add_argument("--extcap-dir", metavar="DIR",
                   help="write the Wireshark extcap launcher to DIR (and exit if no input given)")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no status lines on stderr (listening, auto lock); errors still")


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "monitor", help="decode a bus: FAP, exec async, mikroC, G485; JSON, pcap",
                    description=DESCRIPTION, example=EXAMPLE)
    add_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The command (errors reach :func:`run_command`, the one error path of ``fap``)."""
    from fap_py.errors import PortError
    from fap_py.vbus import CaptureFormatError

    try:
        return _run(args)
    except CaptureFormatError as exc:    # an unreadable file, not bad arguments: exit 3
        raise PortError(errno.EINVAL, str(exc)) from exc


def _run(args: argparse.Namespace) -> int:
    from fap_py.monitor import install

    wrote = False
    if args.dissectors:
        for path in install.write_dissectors(args.dissectors):
            print(f"wrote {path}", file=sys.stderr)
        wrote = True
    if args.extcap_dir:
        print(f"wrote {install.write_extcap(args.extcap_dir)}", file=sys.stderr)
        wrote = True
    given = [name for name in ("port", "raw", "capture") if getattr(args, name)]
    if len(given) > 1:
        raise UsageError(f"give one input, not {' and '.join('--' + n for n in given)}")
    if wrote and not given:
        return 0
    if args.follow and not args.port:
        raise UsageError("--follow needs --port")
    if not given and sys.stdin.isatty():
        raise UsageError("no input: give --port, --raw or --capture, or pipe bytes to stdin")
    return monitor(args)


#: how long a write may still block after a signal before the output is abandoned, s
STUCK_S = 0.2


class _OutputStuck(Exception):
    """A signal came while a write to stdout or the pcap blocked (nobody reads)."""


def monitor(args: argparse.Namespace, out=None) -> int:
    """Run the monitor over the input named in ``args``; the records go to ``out``.

    SIGTERM (extcap's stop) and SIGINT end every input within a read (at most
    POLL_S on a quiet pipe, 200 ms on a quiet port) with the summary: exit 0
    and 130. The handler only sets a flag, so no KeyboardInterrupt lands
    inside a cffi callback; it is installed before the input opens. A write
    still blocked STUCK_S after a signal (a reader that stopped reading) is
    abandoned: the rest of the output is dropped and the summary goes to stderr.
    """
    stopped: List[int] = []           # the signals received
    writing = [False]                 # an output write is under way (it may block)

    def on_signal(signum, frame) -> None:
        stopped.append(signum)
        if writing[0]:                # a write still blocked STUCK_S later is abandoned
            signal.setitimer(signal.ITIMER_REAL, STUCK_S)

    def on_alarm(signum, frame) -> None:
        if writing[0]:
            writing[0] = False
            raise _OutputStuck()

    old = {}
    if threading.current_thread() is threading.main_thread():   # Python's rule for handlers
        old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
        old[signal.SIGALRM] = signal.signal(signal.SIGALRM, on_alarm)
    try:
        return _monitor(args, out, stopped, writing)
    finally:
        if old:
            signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _monitor(args: argparse.Namespace, out, stopped: List[int], writing: List[bool]) -> int:
    def stop() -> bool:
        return bool(stopped)

    from fap_py.monitor.core import Monitor
    from fap_py.monitor.output import human_line, json_line
    from fap_py.monitor.pcap import PcapWriter
    from fap_py.monitor.sources import LivePort, capture_file, raw_file, stream
    from fap_py.monitor.stats import Stats

    out = out or sys.stdout
    baud = args.baud or 0
    live: Optional[LivePort] = None
    fh = None
    pcap = None
    try:
        if args.port:
            live = LivePort(args.port, baud or 115200, rs485_from_args(args))
            baud = live.baud
            # tells a person (and a test) that bytes from now on are seen
            if not args.quiet:
                print(f"fap monitor: listening on {args.port} at {baud} baud", file=sys.stderr,
                      flush=True)
        elif args.raw:
            fh = open(args.raw, "rb")
        elif args.capture:
            cap_baud, cap_chunks = capture_file(args.capture, stop)
            baud = baud or cap_baud
        # after the input: an extcap fifo's reader sees the header once the port is open
        pcap = PcapWriter(open(args.pcap, "wb")) if args.pcap else None
    except BaseException:
        if live is not None:
            live.close()
        if fh is not None:
            fh.close()
        raise
    mon = Monitor(args.protocol, baud)
    stats = Stats(baud)
    # a live port or a pipe: each read's records are on stdout before the next read
    flush = bool(live) or not (args.raw or args.capture)
    # wall-clock times (live port, stdin) are shown from the first record on
    relative = args.capture is None and args.raw is None
    t0: List[Optional[float]] = [None]
    announced = [mon.locked is not None]

    def announce() -> None:
        if announced[0] or not mon.locked:
            return
        announced[0] = True
        if args.quiet:
            return
        if mon.lock_frames:
            print(f"fap monitor: auto: locked on {mon.locked} ({mon.lock_frames} good frames)",
                  file=sys.stderr)
        else:
            print(f"fap monitor: auto: no protocol recognised (no good frame in "
                  f"{mon.bytes} bytes); showing the bytes as {mon.locked}", file=sys.stderr)

    def emit(recs) -> None:
        announce()
        writing[0] = not stopped
        try:
            for rec in recs:
                stats.add(rec)
                if pcap:
                    pcap.write(rec)
                if args.stats:
                    continue
                if args.json:
                    out.write(json_line(rec) + "\n")
                else:
                    if t0[0] is None and rec.t is not None and relative:
                        t0[0] = rec.t
                    out.write(human_line(rec, t0[0]) + "\n")
            if flush and recs:
                out.flush()
                if pcap:
                    pcap.flush()
        finally:
            writing[0] = False

    stuck = False
    try:
        if live is not None:
            with live:
                for chunk in live.chunks(mon.idle_deadline, None if args.follow else args.idle,
                                         stop):
                    if chunk is None:
                        emit(mon.idle(live_now()))
                    else:
                        emit(mon.feed(chunk.data, chunk.t, chunk.char_s, chunk.port,
                                      chunk.now_ns))
        else:
            if fh is not None:
                chunks = raw_file(fh, stop)
            elif args.capture:
                chunks = cap_chunks
            else:
                chunks = stream(sys.stdin.fileno(), baud, stop)
            for chunk in chunks:
                emit(mon.feed(chunk.data, chunk.t, chunk.char_s, chunk.port, chunk.now_ns))
                if stopped:
                    break
        emit(mon.finish())
    except _OutputStuck:
        # nobody reads stdout (or the pcap fifo): drop what is still buffered there
        stuck = True
        _drop_output(out, pcap)
        pcap = None
    finally:
        if fh is not None:
            fh.close()
        if pcap:
            pcap.close()
            pcap._fh.close()
    if stuck:
        if args.quiet:           # Wireshark's extcap takes any stderr text for an error
            return EXIT_INTERRUPTED if signal.SIGINT in stopped else 0
        out = sys.stderr
    stats.bytes = mon.bytes
    announce()
    if args.json and args.stats:
        summary = stats.summary()
        summary["protocol"] = mon.locked
        out.write(json.dumps({"stats": summary}) + "\n")
    elif not args.json:
        out.write(stats.footer() + "\n")
    out.flush()
    return EXIT_INTERRUPTED if signal.SIGINT in stopped else 0


def _drop_output(out, pcap) -> None:
    """Point stdout and the pcap at /dev/null: their buffered bytes can never be written."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fh in (out, pcap._fh if pcap else None):
            try:
                if fh is not None:
                    os.dup2(devnull, fh.fileno())
            except (OSError, ValueError, AttributeError):
                pass
    finally:
        os.close(devnull)


def live_now() -> int:
    from fap_py._native import lib

    return lib.fap_port_now_ns()


__all__ = ["add_arguments", "monitor", "register", "run"]
