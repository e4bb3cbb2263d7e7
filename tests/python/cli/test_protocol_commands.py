"""Each protocol's `fap <name>` command is its plug-in fap_py.commands.protocols.<name>, found
through the protocol table, and reads its numbers (node range, broadcast, default baud) from
the table's row."""
from __future__ import annotations

import argparse
from typing import Dict

from fap_py import _protocols
from fap_py.cli import build_parser


def _actions(parser: argparse.ArgumentParser) -> Dict[str, argparse.Action]:
    return {s: a for a in parser._actions for s in a.option_strings}


def _sub(parser: argparse.ArgumentParser, *path: str) -> argparse.ArgumentParser:
    for name in path:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    return parser


def test_every_protocol_with_a_cli_plugin_has_its_command() -> None:
    top = build_parser()
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    for p in _protocols.all_protocols():
        assert p.has_plugin("cli") and p.name in sub.choices, p.name


def test_scan_ranges_and_default_baud_come_from_the_table() -> None:
    parser = build_parser()
    for name in ("exec", "g485"):
        p = _protocols.get(name)
        scan = _actions(_sub(parser, name, "scan"))
        assert (scan["--first"].default, scan["--last"].default) == (p.node_min, p.node_max)
        assert scan["--baud"].default == p.default_baud
    assert _actions(_sub(parser, "fap", "master"))["--baud"].default == _protocols.get("fap").default_baud


def test_limits_in_errors_and_help_are_the_table_s(fap) -> None:
    p = _protocols.get("fap")
    r = fap("fap", "master", "--port", "x", "--slaves", str(p.node_max + 1))
    assert r.code == 2 and f"slave IDs are {p.node_min}..{p.node_max}" in r.err
    e = _protocols.get("exec")
    r = fap("exec", "scan", "--port", "x", "--last", str(e.node_max + 1))
    assert r.code == 2 and f"--last <= {e.node_max}" in r.err
    assert f"{e.broadcast} = broadcast" in fap("exec", "master", "--help").out
    m = _protocols.get("mikroc")
    assert f"({m.broadcast} = broadcast)" in fap("mikroc", "master", "--help").out
