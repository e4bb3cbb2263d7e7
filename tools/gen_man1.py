#!/usr/bin/env python3
"""Generate the man1 pages of the ``fap`` command from its argparse parsers.

    gen_man1.py OUTDIR [--native-dir DIR] [--date YYYY-MM-DD]

Writes fap.1 and one fap-<command>.1 per subcommand (its actions, e.g.
``fap exec master``, are sections of that page). Everything comes from
``fap_py.cli.build_parser()``: names, usage, descriptions, every option with
its help and default, examples, exit codes; so the pages cannot drift from
``fap --help``. Run by meson at build time (man/meson.build); --native-dir
names the build directory holding the compiled ``fap_py._native`` when the
package is imported from the source tree.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import re
import sys
import textwrap
from pathlib import Path
from typing import Any, List, Optional, Tuple

ROOT = Path(__file__).resolve().parent.parent


def import_cli(native_dir: Optional[str]) -> Any:
    """fap_py.cli from this source tree; fap_py._native from native_dir."""
    if native_dir:
        pkg = ROOT / "fap_py"
        spec = importlib.util.spec_from_file_location(
            "fap_py", pkg / "__init__.py",
            submodule_search_locations=[str(pkg), str(Path(native_dir).resolve())])
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules["fap_py"] = module
        spec.loader.exec_module(module)
    import fap_py.cli as cli
    return cli


def esc(text: str) -> str:
    return text.replace("\\", "\\e")


def safe(line: str) -> str:
    return "\\&" + line if line.startswith((".", "'")) else line


def fill(text: str) -> str:
    lines = textwrap.wrap(esc(" ".join(text.split())), 78, break_long_words=False,
                          break_on_hyphens=False)
    return "\n".join(safe(ln) for ln in lines)


def literal(text: str) -> List[str]:
    return [".nf"] + [safe(esc(ln.rstrip())) for ln in text.rstrip().splitlines()] + [".fi"]


def subcommands(parser: argparse.ArgumentParser) -> List[Tuple[str, str, argparse.ArgumentParser]]:
    """(name, help, parser) of each subcommand, aliases left out."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                out.append((choice.dest, choice.help or "", action.choices[choice.dest]))
    return out


def usage(parser: argparse.ArgumentParser) -> str:
    return re.sub(r"^usage:\s*", "", parser.format_usage().strip())


COMMON = {"help", "verbose", "debug"}   # on every parser: described once, in fap(1)


def options(parser: argparse.ArgumentParser, common: bool = False) -> List[str]:
    """Positional arguments and options as a tagged list (-h, -v and --debug
    only when common is true)."""
    fmt = parser._get_formatter()
    out: List[str] = []
    for action in parser._actions:
        if action.help == argparse.SUPPRESS or isinstance(action, argparse._SubParsersAction):
            continue
        if action.dest in COMMON and not common:
            continue
        if action.option_strings:
            tag = ", ".join(action.option_strings)
            if action.nargs != 0:
                tag += " " + fmt._format_args(action, action.dest.upper())
        else:
            tag = fmt._format_args(action, action.dest)
        helptext = fmt._expand_help(action) if action.help else ""
        out += [".TP", f'.B "{esc(tag)}"', fill(helptext) if helptext else "\\&"]
    return out


def header(name: str, date: str, version: str) -> str:
    return f'.TH {name.upper()} 1 {date} "fap_py {version}" "fap Manual"'


def epilog_sections(parser: argparse.ArgumentParser) -> List[str]:
    if not parser.epilog:
        return []
    return [".SH EXAMPLES"] + literal(parser.epilog)


def command_page(name: str, helptext: str, parser: argparse.ArgumentParser, date: str,
                 version: str) -> str:
    page = [header(f"fap-{name}", date, version), ".SH NAME",
            fill(f"fap-{name} \\- {helptext}").replace("\\e-", "\\-", 1),
            ".SH SYNOPSIS"] + literal(usage(parser))
    page += [".SH DESCRIPTION", fill(parser.description or helptext)]
    actions = subcommands(parser)
    if actions:
        page += [".PP", fill("Actions: " + ", ".join(f"fap {name} {a}" for a, _, _ in actions)
                             + "; each is described below.")]
    page += [".SH OPTIONS"] + options(parser) + [
        ".TP", '.B "-h, --help, -v, --verbose, --debug"', "as for", ".BR fap (1)."]
    for action, ahelp, aparser in actions:
        page += [f'.SH "FAP {esc(name.upper())} {esc(action.upper())}"'] + literal(usage(aparser))
        page += [".PP", fill(aparser.description or ahelp)]
        page += options(aparser)
        if aparser.epilog:
            page += [".PP", "Example:"] + literal(aparser.epilog.replace("example:\n", "", 1))
    page += epilog_sections(parser)
    page += [".SH EXIT STATUS", "See", ".BR fap (1)."]
    page += [".SH SEE ALSO", ".BR fap (1),", ".BR libfap (7)"]
    return "\n".join(page) + "\n"


def main_page(parser: argparse.ArgumentParser, commands: List[Tuple[str, str, Any]],
              exit_codes: dict, date: str, version: str) -> str:
    page = [header("fap", date, version), ".SH NAME",
            fill("fap \\- " + (parser.description or "")).replace("\\e-", "\\-", 1),
            ".SH SYNOPSIS"] + literal(usage(parser))
    page += [".SH DESCRIPTION", fill(parser.description or ""), ".PP",
             fill("Options -v, -vv and --debug are accepted before or after the command. "
                  "Each command has its own page, fap-COMMAND(1), and its own --help.")]
    page += [".SH COMMANDS"]
    for name, helptext, _ in commands:
        page += [".TP", f".BR fap-{esc(name)} (1)", fill(helptext)]
    page += [".SH OPTIONS"] + options(parser, common=True)
    examples = (parser.epilog or "").split("exit codes:")[0].replace("examples:\n", "", 1)
    if examples.strip():
        page += [".SH EXAMPLES"] + literal(examples)
    page += [".SH EXIT STATUS"]
    for code, text in exit_codes.items():
        page += [".TP", f".B {code}", fill(text)]
    page += [".SH SEE ALSO"]
    refs = [f".BR fap-{esc(n)} (1)," for n, _, _ in commands] + [".BR libfap (7)"]
    page += refs
    return "\n".join(page) + "\n"


def main(argv: List[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("outdir")
    ap.add_argument("--native-dir")
    ap.add_argument("--date", default=os.environ.get("FAP_MAN_DATE", "2026-11-26"))
    args = ap.parse_args(argv)
    os.environ["COLUMNS"] = "80"          # argparse wraps usage lines to fit
    cli = import_cli(args.native_dir)
    from fap_py import __version__
    from fap_py.commands._options import EXIT_CODES
    parser = cli.build_parser()
    commands = subcommands(parser)
    out = Path(args.outdir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.1"):           # a removed command loses its page
        old.unlink()
    (out / "fap.1").write_text(main_page(parser, commands, EXIT_CODES, args.date, __version__))
    for name, helptext, sub in commands:
        (out / f"fap-{name}.1").write_text(command_page(name, helptext, sub, args.date, __version__))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
