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
import logging
import signal
import sys
from typing import IO, TYPE_CHECKING, Callable, Optional

from . import _options as opt  # as the protocol rooms use it

if TYPE_CHECKING:  # pragma: no cover
    from fap_py.monitor.session import SessionConfig

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
    from fap_py.monitor.session import LIVE_BAUD, protocol_choice, protocol_choices

    # choices for the help and shell completion; the type also takes an alias (execasync)
    p.add_argument("--protocol", type=_choice(protocol_choice), choices=protocol_choices(),
                   default="auto", help="decoder; auto tries every protocol and reports which one locks on")
    opt.add_port_options(p, baud_default=None, port_required=False, rs485_default="none",
                     port_help="live serial port, opened receive-only (or give --raw, --capture, "
                     "or bytes on stdin)",
                     baud_help=f"line rate: opens --port at it ({LIVE_BAUD} if not given); sets the "
                     "inter-byte gap and bus utilisation for the other inputs (a capture's own "
                     "rate if not given)")
    src = p.add_argument_group("other inputs (instead of --port)")
    src.add_argument("--raw", metavar="FILE", help="raw bytes as recorded from a port")
    src.add_argument("--capture", metavar="FILE",
                     help="virtual-bus capture (fap bus --capture): senders and times kept")
    p.add_argument("--follow", action="store_true",
                   help="live port: keep reading until interrupted (else stop after --idle "
                        "seconds of silence)")
    p.add_argument("--idle", type=opt.seconds, default=2.0, metavar="S",
                   help="live port without --follow: stop after this much silence, seconds")
    opt.add_output_options(p)
    p.add_argument("--stats", action="store_true",
                   help="print only the statistics (frames, errors per node, reply times)")
    p.add_argument("--pcap", metavar="FILE", help="also write every frame to this pcap file")
    p.add_argument("--dissectors", metavar="DIR",
                   help="write the Wireshark Lua dissector to DIR (and exit if no input given)")
    p.add_argument("--extcap-dir", metavar="DIR",
                   help="write the Wireshark extcap launcher to DIR (and exit if no input given)")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no status lines on stderr (listening, auto lock); errors still")
    p.add_argument("--sim-control", metavar="unix:PATH",
                   help="a fap sim running on the bus (its --control socket): its counters "
                        "(requests served, faults applied, per node) follow the summary")


def _choice(convert: Callable[[str], str]) -> Callable[[str], str]:
    """An argparse type: ``convert``'s value, its error as a usage error naming the value."""
    def parse(text: str) -> str:
        from fap_py.errors import InvalidValueError

        try:
            return convert(text)
        except InvalidValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = "protocol"
    return parse


def register(sub: argparse._SubParsersAction) -> None:
    p = opt.add_command(sub, "monitor", help="decode a bus: FAP, exec async, mikroC, G485; JSON, pcap",
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
        raise opt.UsageError(f"give one input, not {' and '.join('--' + n for n in given)}")
    if wrote and not given:
        return 0
    if args.follow and not args.port:
        raise opt.UsageError("--follow needs --port")
    if not given and sys.stdin.isatty():
        raise opt.UsageError("no input: give --port, --raw or --capture, or pipe bytes to stdin")
    return monitor(args)


def config_from_args(args: argparse.Namespace) -> "SessionConfig":
    """The session the arguments describe (already checked by :func:`_run`)."""
    from fap_py.monitor.session import SessionConfig

    return SessionConfig(
        protocol=args.protocol, device=args.port, raw_file=args.raw, capture_file=args.capture,
        baud=args.baud or 0, rs485=opt.rs485_from_args(args) if args.port else None,
        idle_s=None if args.follow else args.idle, as_json=bool(args.json),
        stats_only=bool(args.stats), pcap_file=args.pcap, quiet=bool(args.quiet))


def monitor(args: argparse.Namespace, out: Optional[IO[str]] = None) -> int:
    """Run the monitor session the arguments describe; the records go to ``out``
    (stdout if None). Exit 0 at the input's end or on SIGTERM, 130 on SIGINT
    (:class:`fap_py.monitor.session.Session` has the session itself)."""
    from fap_py.monitor.session import Session

    sim = getattr(args, "sim_control", None)
    if sim:
        from fap_py.sim._control import counters

        counters(sim)     # a sim that does not answer: the error now, before the input is read
    ended_by = Session(config_from_args(args), out).run()
    if sim:
        _sim_summary(args, sim, out or sys.stdout)
    return opt.EXIT_INTERRUPTED if ended_by == signal.SIGINT else 0


def _sim_summary(args: argparse.Namespace, spec: str, out: IO[str]) -> None:
    """The sim's counters after the monitor's own summary: its totals, then each bus and
    node as ``fap sim status`` prints them; with ``--json`` one ``{"event": "sim", ...}``
    line (the sim's status answer)."""
    import json

    from fap_py.errors import FapError
    from fap_py.sim._control import counters

    from .sim import counters_text, status_lines

    try:
        st = counters(spec)
    except FapError as exc:     # the sim stopped first: the monitor's own result stands
        log.warning("--sim-control: %s", exc)
        return
    if args.json:
        out.write(json.dumps({"event": "sim", "control": spec, **st}) + "\n")
    else:
        out.write("\n".join([f"sim ({spec}): {counters_text(st)}", *status_lines(st)]) + "\n")
    out.flush()


__all__ = ["add_arguments", "monitor", "register", "run"]
