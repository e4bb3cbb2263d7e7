"""``fap doctor``: why a serial port does not work, found with evidence and the exact fix.

A thin command over :mod:`fap_py.doctor` (the checks, ``--listen``,
``--bundle``): docs/doctor.md lists every check and the exit codes.
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import List

from ..doctor import LISTEN_MAX_S  # the longest --listen: the library's bound (doctor.listen)
from ._options import UsageError, add_command, add_output_options, baud, emit, seconds


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(
        sub, "doctor", help="find why a serial port does not work: evidence and the exact fix",
        description="Check the machine (or a tree copied off one, --root) for the common causes "
        "of a dead serial bus: groups, other programs on the port, brltty, ModemManager, a "
        "getty or the console, the Raspberry Pi UART mapping, unstable names, under-voltage, "
        "adapter latency and RS-485 support. Never changes anything. Exit code: 0 ok/info, "
        "4 warning, 5 error (2 usage).",
        example="fap doctor\nfap doctor /dev/ttyUSB0 --user pi\n"
        "fap doctor /dev/serial0 --root ./copied-tree --json\n"
        "fap doctor /dev/ttyUSB0 --listen 10\nfap doctor --bundle doctor.tar.gz")
    p.add_argument("port", metavar="PORT", nargs="?",
                   help="the port to check (default: every serial port found)")
    p.add_argument("--root", metavar="DIR", default="/",
                   help="analyse the tree under DIR (its /sys /proc /dev /etc /boot /run) instead of /")
    p.add_argument("--user", metavar="NAME",
                   help="the user to check (default: the invoking user; under --root the User= "
                   "of a fap unit)")
    p.add_argument("--kernel-log", metavar="FILE",
                   help="the kernel log (default: DIR/var/log/kern.log or DIR/dmesg; dmesg at /)")
    p.add_argument("--baud", metavar="N", type=baud,
                   help="the rate you use: compared with the port's current termios")
    p.add_argument("--listen", metavar="SECONDS", type=seconds,
                   help="listen on PORT (never transmitting) and name the protocol and baud")
    p.add_argument("--bundle", metavar="FILE",
                   help="write the evidence as a tar.gz (passwords and tokens masked)")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..doctor import _bundle, _listen, exit_code
    from ..doctor._context import Context
    from ..doctor._finding import ordered
    from ..doctor._registry import run as run_checks
    from .ports import probe as ports_probe

    if not os.path.isdir(args.root):
        raise UsageError(f"--root {args.root}: not a directory")
    if args.listen is not None:
        if not args.port:
            raise UsageError("--listen needs a PORT")
        if os.path.abspath(args.root) != "/":
            raise UsageError("--listen listens on this machine's port: not with --root")
        if not 0 < args.listen <= LISTEN_MAX_S:
            raise UsageError(f"--listen must be in 0..{LISTEN_MAX_S:g} seconds")
    ctx = Context(root=args.root, port=args.port, user=args.user, kernel_log=args.kernel_log,
                  baud=args.baud, prober=ports_probe)   # `fap ports`' verdict, one probe
    findings = run_checks(ctx)
    if args.listen is not None:
        host = ctx.host(args.port) or args.port
        findings.append(_listen.listen(host, args.listen))
    findings = ordered(findings)
    if args.bundle:
        n = _bundle.write(args.bundle, ctx, findings)
        sys.stderr.write(f"fap doctor: wrote {args.bundle} ({n} evidence files, secrets masked)\n")
    code = exit_code(findings)
    if args.json:
        for f in findings:
            emit(args, f.as_event(), None)
        emit(args, {"event": "summary", "worst": findings[0].severity if findings else "ok",
                    "findings": len(findings), "exit": code, "root": ctx.root,
                    "user": ctx.user}, None)
    elif sys.stdout.isatty():
        _rich(findings, ctx, code)
    else:
        for line in _plain(findings):
            print(line, flush=True)
    return code


def _plain(findings: List) -> List[str]:
    out = []
    for f in findings:
        out.append(f"{f.severity.upper():<7} {f.id}" + (f" [{f.port}]" if f.port else "")
                   + f": {f.cause}")
        out += [f"        evidence: {e}" for e in f.evidence]
        if f.fix and f.severity != "ok":
            lines = f.fix.splitlines()
            out.append(f"        fix: {lines[0]}")
            out += [f"             {line}" for line in lines[1:]]
    return out


_STYLE = {"error": "bold red", "warning": "yellow", "info": "cyan", "ok": "green"}


def _rich(findings: List, ctx: object, code: int) -> None:
    from rich.console import Console
    from rich.markup import escape

    con = Console(highlight=False)
    for f in findings:
        head = f"[{_STYLE[f.severity]}]{f.severity.upper():<7}[/] [bold]{escape(f.id)}[/]"
        if f.port:
            head += f" {escape(f.port)}"
        con.print(f"{head}: {escape(f.cause)}")
        if f.severity == "ok":
            continue
        for e in f.evidence:
            con.print(f"    [dim]evidence:[/] {escape(e)}")
        if f.fix:
            con.print("    [bold]fix:[/] " + escape(f.fix).replace("\n", "\n         "))
    con.print(f"[dim]exit {code}[/]")
