"""The ``fap`` console command: ``fap --help`` lists the subcommands.

Each module in :mod:`fap_py.commands` (not starting with ``_``) defines
``register(subparsers)``, and so does each protocol's command plug-in, found by
name through the protocol table (``fap_py.commands.protocols.<name>``, see
:mod:`fap_py._protocols`); the shared options, output and error path live in
:mod:`fap_py.commands._options`. docs/cli.md documents every command.
"""
from __future__ import annotations

import importlib
import logging
import pkgutil
import sys
from typing import List, Optional, Tuple

from . import __version__, _protocols, commands
from .commands._options import (
    EXIT_CODES,
    EXIT_USAGE,
    Parser,
    add_global_flags,
    run_command,
    split_global_flags,
)

EXAMPLE = """\
examples:
  fap demo                                  # live FAP bus in this terminal, no hardware
  fap ports                                 # serial ports and their RS-485 support
  fap exec master --port /dev/ttyUSB0 --node 5 0102 --count 0 --interval 0.5
  fap g485 scan --port /dev/ttyUSB0 --json

exit codes:
""" + "\n".join(f"  {code:<4} {text}" for code, text in EXIT_CODES.items())


def build_parser() -> Parser:
    parser = Parser(
        prog="fap",
        description="RS-485 toolkit: FAP, exec async, mikroC RS-485 and Gicren G485 "
        "on real serial ports and on a virtual multi-drop bus.",
        epilog=EXAMPLE,
    )
    parser.add_argument("--version", action="version", version=f"fap_py {__version__}")
    add_global_flags(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for _, name in sorted(_command_modules()):
        register = getattr(importlib.import_module(name), "register", None)
        if register is not None:
            register(sub)
    return parser


def _command_modules() -> List[Tuple[str, str]]:
    """(sort key, module) of every command: the modules of :mod:`fap_py.commands` and each
    protocol's command plug-in (a protocol without one has no command)."""
    found = [(info.name, f"{commands.__name__}.{info.name}")
             for info in pkgutil.iter_modules(commands.__path__)
             if not info.name.startswith("_") and not info.ispkg]
    found += [(p.name, p.plugin_name("cli")) for p in _protocols.all_protocols() if p.has_plugin("cli")]
    return found


class _Formatter(logging.Formatter):
    """The log format, with ``levelname_lower`` (``warning``) for the plain line."""

    def format(self, record: logging.LogRecord) -> str:
        record.levelname_lower = record.levelname.lower()
        return super().format(record)


def setup_logging(verbose: int, debug: bool) -> None:
    """-v info, -vv (or --debug) debug; the wire loggers (``fap_py.wire.*``)
    log every frame at debug."""
    level = logging.WARNING if not (verbose or debug) else \
        logging.INFO if verbose == 1 and not debug else logging.DEBUG
    # without -v only warnings show: one plain line each (``fap: warning: ...``), as errors
    fmt = "fap: %(levelname_lower)s: %(message)s" if level == logging.WARNING else \
        "%(asctime)s %(name)s %(levelname)s %(message)s"
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Formatter(fmt))
    logging.basicConfig(level=level, handlers=[handler])
    logging.getLogger().setLevel(level)


def main(argv: Optional[List[str]] = None) -> int:
    rest, verbose, debug = split_global_flags(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser()
    except _protocols.UnknownProtocolError as exc:   # a bad FAP_EXTRA_PROTOCOLS entry
        sys.stderr.write(f"fap: error: {exc}\n")
        return EXIT_USAGE
    try:
        args = parser.parse_args(rest)
    except SystemExit as exc:          # --help, --version, usage errors
        return int(exc.code or 0) if isinstance(exc.code, int) else EXIT_USAGE
    args.verbose, args.debug = verbose, debug
    setup_logging(verbose, debug)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    return run_command(args.func, args)


if __name__ == "__main__":
    sys.exit(main())
