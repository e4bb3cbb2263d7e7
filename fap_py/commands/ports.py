"""``fap ports``: the machine's serial ports and whether each does kernel RS-485.

Ports come from sysfs (:mod:`fap_py.sysfs_ports`: driver, USB VID:PID,
serial, ``/dev/serial/by-id`` name, FTDI latency timer); each one is then
probed through the C port layer (``fap_port_probe``: termios,
``TIOCGRS485`` and the same config written back with ``TIOCSRS485``,
nothing changed). A driver without RS-485 answers ENOTTY ("no"); a plain
16550 reports a config but cannot set one ("read-only"); a port another
program holds is "busy" and never opened (an open raises RTS under it).
"""
from __future__ import annotations

import argparse
import errno
import os
from typing import Any, Callable, Dict, List

from .. import sysfs_ports
from ..port import port_kind
from ..rs485 import DEFAULT_BAUD
from ._options import BusError, UsageError, add_command, add_output_options, baud, count, emit, seconds

#: where ports are looked up (tests point these at a fake tree)
SYSFS_ROOT = "/sys"
DEV_ROOT = "/dev"

# linux/serial.h SER_RS485_* bits: the kernel ABI, named for the listing
_RS485_FLAGS = ((1 << 0, "enabled"), (1 << 1, "rts_on_send"), (1 << 2, "rts_after_send"),
                (1 << 4, "rx_during_tx"), (1 << 5, "terminate_bus"))


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "ports", help="list serial ports, their RS-485 support and configuration",
                    example="fap ports\nfap ports --all --json\nfap ports --device /dev/pts/3\n"
                    "fap ports --check /dev/ttyS0 --baud 9600")
    p.add_argument("--all", action="store_true",
                   help="also serial_core slots without a UART (sysfs type 0: empty ttyS* slots)")
    p.add_argument("--device", metavar="PATH", action="append", type=_path("--device"),
                   help="probe this path too (e.g. a pty of `fap bus`; a tcp:// or rfc2217:// "
                   "URL is listed, not probed); repeatable")
    p.add_argument("--no-probe", action="store_true",
                   help="do not open the ports (opening a tty raises DTR/RTS)")
    c = p.add_argument_group("direction check (--check)")
    c.add_argument("--check", metavar="PATH", type=_path("--check"),
                   help="time the release of the direction line against the transceiver's echo "
                   "of a test pattern on PATH (a device or a tcp:// / rfc2217:// URL), and "
                   "recommend a mode")
    c.add_argument("--baud", metavar="N", type=baud, default=DEFAULT_BAUD, help="--check: baud rate")
    c.add_argument("--rs485", choices=("soft", "none"), default=None,
                   help="--check: the mode to time (default: soft, which falls back to none, "
                   "and says so, on a port without an RTS line such as a pty; none on a "
                   "network URL, whose server switches the direction)")
    c.add_argument("--rts-after", metavar="MS", type=seconds, default=0.0,
                   help="--check: last bit -> RTS released, milliseconds")
    c.add_argument("--rounds", metavar="N", type=count, default=5, help="--check: patterns sent")
    add_output_options(p)
    p.set_defaults(func=run)


def is_network(path: str) -> bool:
    """A URL (an Ethernet serial server), not a device path: the port layer's
    own reading (:func:`fap_py.port.port_kind`). No local RS-485 direction to
    probe or time; a URL libfap cannot open is refused by the open, naming why."""
    return port_kind(path) != "device"


def _path(option: str) -> "Callable[[str], str]":
    """argparse type of ``--check`` / ``--device``: a non-empty path or URL (an
    empty one would be silently ignored)."""
    def parse(text: str) -> str:
        if not text or "\0" in text:
            raise argparse.ArgumentTypeError(f"needs a device path or a tcp:// / rfc2217:// "
                                             f"URL, not {text!r}")
        return text
    return parse


def probe(path: str) -> Dict[str, Any]:
    """What the C port layer reads from ``path``: baud and RS-485 state."""
    from .._native import ffi, lib

    baud = ffi.new("unsigned *")
    flags = ffi.new("uint32_t *")
    before = ffi.new("uint32_t *")
    after = ffi.new("uint32_t *")
    r = lib.fap_port_probe(os.fsencode(path), baud, flags, before, after)
    info: Dict[str, Any] = {}
    if r in (0, 1, -errno.ENOTTY):
        info["baud"] = int(baud[0]) or None
    if r in (0, 1):
        names = [n for bit, n in _RS485_FLAGS if flags[0] & bit]
        info.update(rs485="yes" if r == 0 else "read-only", rs485_enabled=bool(flags[0] & 1),
                    rs485_flags=names, rts_before_ms=int(before[0]), rts_after_ms=int(after[0]))
    elif r == -errno.ENOTTY:
        info["rs485"] = "no"
    elif r == -errno.EBUSY:
        info["rs485"] = "busy"   # held by another program: not opened
    else:
        info.update(rs485="unknown", error=os.strerror(-r))
    return info


def check(args: argparse.Namespace) -> int:
    """``--check PATH``: exit 0 when the release follows the last echoed
    byte in every round, 1 when it does not (or nothing came back)."""
    from ..direction_check import measure
    from ..errors import PortError
    from ..rs485 import RS485, RS485Mode

    notes: List[str] = []
    if is_network(args.check):
        if args.rs485 == "soft":
            raise UsageError(f"{args.check}: --rs485 soft: a network port has no RTS line here "
                             "(the server switches the direction); use --rs485 none, the "
                             "default for a URL")
        state: Dict[str, Any] = {}
        mode = RS485Mode.NONE
    else:
        state = probe(args.check)
        if state.get("rs485") == "busy":
            raise BusError(f"{args.check}: busy: held by another program (not opened)")
        mode = RS485Mode.NONE if args.rs485 == "none" else RS485Mode.SOFT_RTS
    line = RS485(mode=mode, delay_after_send_us=round(args.rts_after * 1000))
    try:
        res = measure(args.check, args.baud, line, rounds=args.rounds,
                      kernel_rs485=state.get("rs485") == "yes")
    except PortError as exc:
        if exc.errno != errno.ENOTTY or mode != RS485Mode.SOFT_RTS or args.rs485 == "soft":
            raise                  # an explicit --rs485 soft the port cannot do: exit 3
        res = measure(args.check, args.baud, RS485(mode=RS485Mode.NONE), rounds=args.rounds,
                      kernel_rs485=False)   # no RTS line here (a pty): time the drain only
        notes.append("the port has no RTS line (a pty, say): timed with --rs485 none, not "
                     "the default soft")
    row = {"event": "check", "device": res.device, "mode": res.mode, "rounds": res.rounds,
           "echoed": res.echoed, "collisions": res.collisions, "release_us": res.release_us,
           "margins_us": list(res.margins_us), "recommend": res.recommend,
           "warnings": list(res.warnings), "notes": notes}
    if res.margins_us:
        med = res.release_us or 0
        text = (f"{res.device}: mode {res.mode}, line released {abs(med)} us "
                f"{'after' if med >= 0 else 'before'} the last echoed byte (median of "
                f"{len(res.margins_us)}; {min(res.margins_us)}..{max(res.margins_us)} us, + = after); "
                f"recommended mode: {res.recommend}")
    else:
        text = f"{res.device}: mode {res.mode}, no echo; recommended mode: {res.recommend}"
    emit(args, row, "\n".join([text] + [f"  note: {n}" for n in notes]
                              + [f"  warning: {w}" for w in res.warnings]))
    return 1 if res.warnings else 0


def run(args: argparse.Namespace) -> int:
    if args.check is not None:
        return check(args)
    rows: List[Dict[str, Any]] = []
    seen = set()
    for port in sysfs_ports.list_ports(SYSFS_ROOT, DEV_ROOT, include_empty=args.all):
        rows.append({"event": "port", "device": port.device, "description": port.description,
                     "driver": port.driver, "uart_type": port.uart_type,
                     "vid_pid": port.vid_pid, "serial": port.serial, "by_id": port.by_id,
                     "latency_timer_ms": port.latency_timer_ms})
        seen.add(port.device)
    for path in args.device or ():
        if path not in seen:
            rows.append({"event": "port", "device": path, "description": "given with --device"})
    for row in rows:
        if is_network(row["device"]):     # a URL, not a file: nothing local to probe
            row.update(rs485="network")
        elif not args.no_probe:
            row.update(probe(row["device"]))
        emit(args, row, _human(row))
    if not rows:
        emit(args, {"event": "none"}, "no serial ports found (try --all, or --device PATH)")
    return 0


def _human(row: Dict[str, Any]) -> str:
    text = f"{row['device']:<16} {row['description']}"
    extra = [f"{k} {row[f]}" for k, f in (("driver", "driver"), ("usb", "vid_pid"),
                                          ("serial", "serial"), ("by-id", "by_id"))
             if row.get(f)]
    if row.get("latency_timer_ms") is not None:
        extra.append(f"latency timer {row['latency_timer_ms']} ms")
    if extra:
        text += f" ({', '.join(extra)})"
    rs = row.get("rs485")
    if rs in ("yes", "read-only"):
        state = "enabled" if row["rs485_enabled"] else "disabled"
        kind = "kernel" if rs == "yes" else "reported but not settable (use --rs485 soft)"
        text += (f"  | RS-485: {kind}, {state} ({','.join(row['rs485_flags']) or 'no flags'}, "
                 f"RTS delays {row['rts_before_ms']}/{row['rts_after_ms']} ms)")
    elif rs == "no":
        text += "  | RS-485: no kernel support (ENOTTY)"
    elif rs == "busy":
        text += "  | busy: held by another program (not opened)"
    elif rs == "network":
        text += "  | a network port: not probed (its server switches the RS-485 direction)"
    elif rs == "unknown":
        text += f"  | RS-485: unknown ({row['error']})"
    if row.get("baud"):
        text += f", {row['baud']} baud"
    return text
