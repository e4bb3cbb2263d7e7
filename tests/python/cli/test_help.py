"""`--help` of every `fap` command: snapshots, defaults shown, an example, shared options.

The expected text lives in tests/python/cli/help/<command>.txt. After a
deliberate change, regenerate with

    FAP_UPDATE_HELP=1 pytest tests/python/cli/test_help.py

and review the diff: a help change must be a decision, not an accident.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Dict, Tuple

import pytest

from fap_py.cli import build_parser

HELP_DIR = Path(__file__).resolve().parent / "help"
PORT_OPTIONS = ("--port", "--baud", "--rs485", "--rts-before", "--rts-after", "--rts-polarity")


def _commands() -> Dict[Tuple[str, ...], argparse.ArgumentParser]:
    """Every parser of the command tree, by its path of names (aliases skipped)."""
    found: Dict[Tuple[str, ...], argparse.ArgumentParser] = {}

    def walk(path: Tuple[str, ...], parser: argparse.ArgumentParser) -> None:
        found[path] = parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                seen = set()
                for name, sub in action.choices.items():
                    if id(sub) in seen:
                        continue          # an alias (exec poll = exec master)
                    seen.add(id(sub))
                    walk(path + (name,), sub)

    walk((), build_parser())
    return found


COMMANDS = _commands()
LEAVES = [p for p, parser in COMMANDS.items()
          if not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)]


def _normalise(text: str) -> str:
    # Python < 3.10 says "optional arguments:"
    return text.replace("optional arguments:", "options:")


def _snapshot_name(path: Tuple[str, ...]) -> str:
    return ("fap" if not path else "fap_" + "_".join(path)) + ".txt"


@pytest.mark.parametrize("path", sorted(COMMANDS), ids=lambda p: " ".join(p) or "fap")
def test_help_matches_snapshot(path: Tuple[str, ...], fap) -> None:
    r = fap(*path, "--help")
    assert r.code == 0 and r.err == ""
    text = _normalise(r.out)
    snap = HELP_DIR / _snapshot_name(path)
    if os.environ.get("FAP_UPDATE_HELP"):
        snap.write_text(text)
    assert snap.exists(), f"no snapshot {snap.name}: run FAP_UPDATE_HELP=1 pytest {__file__}"
    assert text == snap.read_text(), f"`fap {' '.join(path)} --help` changed; see module doc"


def test_no_stale_snapshots() -> None:
    expected = {_snapshot_name(p) for p in COMMANDS}
    assert {p.name for p in HELP_DIR.glob("*.txt")} == expected


@pytest.mark.parametrize("path", LEAVES, ids=" ".join)
def test_every_command_has_the_shared_options(path: Tuple[str, ...], fap) -> None:
    parser = COMMANDS[path]
    opts = {s for a in parser._actions for s in a.option_strings}
    assert {"--json", "-v", "--verbose", "--debug", "--help"} <= opts, path
    if "--port" in opts:      # every command on a port has the whole group
        assert set(PORT_OPTIONS) <= opts, path
        # ... and every one that sends has --echo-suppression (docs/cli.md, issue 25)
        assert ("--echo-suppression" in opts) == (path not in (("monitor",), ("web",))), path   # receive-only
    if path[0] == "g485":     # --check confirms a write or a set, nothing else (issue 25)
        assert ("--check" in opts) == (path[1] in ("write", "set")), path
    if "--timeout" in opts:
        assert "--retries" in opts, path
    text = fap(*path, "--help").out
    assert "example:\n  fap " + path[0] in text, "every help ends with an example"
    # every option or argument with a real default shows it
    fmt = parser._get_formatter()
    for a in parser._actions:
        if a.default is None or a.default is False or a.default == argparse.SUPPRESS \
                or isinstance(a, (argparse._HelpAction, argparse._VersionAction)):
            continue
        assert "default" in fmt._get_help_string(a), (path, a.dest)


def test_top_level_help_lists_every_command_and_exit_codes(fap) -> None:
    out = fap("--help").out
    for name in ("bridge", "bus", "demo", "exec", "fap", "g485", "mikroc", "monitor", "ports",
                 "soak", "version"):
        assert f"    {name} " in out
    for line in ("0    ok", "1    the operation failed on the bus", "2    usage error",
                 "3    port or file error", "130  interrupted"):
        assert line in out
