"""Wireshark extcap entry point: live capture from a serial port into Wireshark.

Wireshark runs this program (through the launcher ``fap monitor
--extcap-dir DIR`` writes) with ``--extcap-interfaces``, ``--extcap-dlts``,
``--extcap-config`` and finally ``--capture --fifo PATH``; the capture runs
the monitor session of ``fap monitor --port ... --follow --stats --quiet
--pcap FIFO`` (:mod:`fap_py.monitor.session`) until Wireshark stops it (SIGTERM). Wireshark reports anything on stderr as an error, so the
capture prints nothing there but real errors; the fifo gets its pcap header
once the port is open. See https://www.wireshark.org/docs/man-pages/extcap.html.
"""
from __future__ import annotations

import argparse
import signal
import sys
from typing import List, Optional

from .._project import docs_url
from ..errors import FapError, InvalidTypeError, InvalidValueError
from .pcap import LINKTYPE
from .session import AUTO, LIVE_BAUD, Session, SessionConfig, protocol_choice, protocol_choices

INTERFACE = "fap_monitor"
VERSION = "1.0"


def interfaces() -> str:
    return (f"extcap {{version={VERSION}}}{{help={docs_url('monitor.md')}}}\n"
            f"interface {{value={INTERFACE}}}{{display=fap monitor: FAP, exec async, mikroC, "
            f"G485 on a serial port}}\n")


def dlts() -> str:
    return f"dlt {{number={LINKTYPE}}}{{name=USER0}}{{display=fap monitor record}}\n"


def config() -> str:
    lines = [
        "arg {number=0}{call=--port}{display=Serial port}{type=string}"
        "{tooltip=Device path, e.g. /dev/ttyUSB0}{required=true}",
        f"arg {{number=1}}{{call=--baud}}{{display=Baud rate}}{{type=integer}}{{default={LIVE_BAUD}}}",
        "arg {number=2}{call=--protocol}{display=Protocol}{type=selector}",
    ]
    for p in protocol_choices():
        default = "{default=true}" if p == AUTO else ""
        lines.append(f"value {{arg=2}}{{value={p}}}{{display={p}}}{default}")
    return "\n".join(lines) + "\n"


def main(argv: Optional[List[str]] = None) -> int:
    """Wireshark's calls (``argv`` None: sys.argv); the capture runs a monitor session.

    Exit codes as ``fap``'s (docs/cli.md): 0 (a capture stopped by SIGTERM included),
    2 bad arguments, 3 the port or the fifo cannot be used, 1 any other failure (one
    line on stderr each), 130 on SIGINT."""
    if argv is not None and (not isinstance(argv, list) or
                             not all(isinstance(a, str) for a in argv)):
        raise InvalidTypeError(f"argv must be None or a list of str, not {type(argv).__name__}")
    ap = argparse.ArgumentParser(prog="fap-monitor-extcap")
    ap.add_argument("--extcap-interfaces", action="store_true")
    ap.add_argument("--extcap-interface")
    ap.add_argument("--extcap-dlts", action="store_true")
    ap.add_argument("--extcap-config", action="store_true")
    ap.add_argument("--extcap-version")
    ap.add_argument("--capture", action="store_true")
    ap.add_argument("--fifo")
    ap.add_argument("--port")
    ap.add_argument("--baud", type=int, default=LIVE_BAUD)
    ap.add_argument("--protocol", default=AUTO)
    args, _unknown = ap.parse_known_args(argv)
    try:
        args.protocol = protocol_choice(args.protocol)
    except InvalidValueError as exc:
        print(f"fap: error: --protocol: {exc}", file=sys.stderr)
        return 2
    if args.extcap_interfaces:
        sys.stdout.write(interfaces())
        return 0
    if args.extcap_interface and args.extcap_interface != INTERFACE:
        print(f"fap: error: unknown interface {args.extcap_interface}", file=sys.stderr)
        return 2
    if args.extcap_dlts:
        sys.stdout.write(dlts())
        return 0
    if args.extcap_config:
        sys.stdout.write(config())
        return 0
    if args.capture:
        if not args.fifo or not args.port:
            print("fap: error: --capture needs --fifo and --port", file=sys.stderr)
            return 2
        return _capture(args.port, args.baud, args.protocol, args.fifo)
    print("fap: error: nothing to do (see extcap(4))", file=sys.stderr)
    return 2


def _capture(port: str, baud: int, protocol: str, fifo: str) -> int:
    """Capture ``port`` into the pcap ``fifo`` until SIGTERM (exit 0) or SIGINT (130)."""
    try:
        cfg = SessionConfig(protocol=protocol, device=port, baud=baud, idle_s=None,
                            stats_only=True, pcap_file=fifo, quiet=True)
        ended_by = Session(cfg, sys.stdout).run()
    except (FapError, OSError) as exc:       # Wireshark shows stderr as the error
        text = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        if isinstance(exc, OSError) and exc.filename and str(exc.filename) not in text:
            text = f"{exc.filename}: {text}"
        print(f"fap: error: {text}", file=sys.stderr)
        if isinstance(exc, (InvalidTypeError, InvalidValueError)):
            return 2
        return 3 if isinstance(exc, OSError) else 1
    return 128 + signal.SIGINT if ended_by == signal.SIGINT else 0


__all__ = ["config", "dlts", "interfaces", "main"]

if __name__ == "__main__":
    sys.exit(main())
