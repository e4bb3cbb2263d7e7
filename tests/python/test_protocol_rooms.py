"""Protocol conformance: walks the protocol table (fap_py._protocols) and the tool rooms.

Done-when of the protocol rooms: every protocol has its plug-in for every tool; a tool file
(monitor, bridge, soak, CLI outside the protocols' own plug-in files) carries no protocol
name list, no switch on a protocol name and no re-typed protocol limit or default baud.
Nothing here is a hand-kept list of protocols: it reads the table.
"""

from __future__ import annotations

import ast
import io
import pathlib
import tokenize
from typing import Iterator, List, Set

import pytest

import fap_py
from fap_py import _protocols as P

PKG = pathlib.Path(fap_py.__file__).resolve().parent
TOOL_ROOTS = ("monitor", "bridge", "soak", "commands", "cli.py")


def _spellings() -> Set[str]:
    return {s for p in P.PROTOCOLS for s in (p.name, *p.aliases)}


def _is_plugin(path: pathlib.Path) -> bool:
    """True for a protocol's own plug-in file (its room), where its name and limits belong."""
    rel = path.relative_to(PKG).with_suffix("")
    names = {p.name for p in P.PROTOCOLS}
    for room in P.TOOLS.values():
        parts = tuple(room.split("."))
        if rel.parts[:-1] == parts and rel.parts[-1] in names:
            return True
        if rel.parts[:len(parts)] == parts and len(rel.parts) > len(parts) + 1 and rel.parts[len(parts)] in names:
            return True   # a protocol's plug-in package (room/<name>/...)
    return False


def tool_files() -> Iterator[pathlib.Path]:
    for root in TOOL_ROOTS:
        base = PKG / root
        files = [base] if base.is_file() else sorted(base.rglob("*.py"))
        for f in files:
            if not _is_plugin(f):
                yield f


@pytest.mark.parametrize("proto", P.PROTOCOLS, ids=lambda p: p.name)
@pytest.mark.parametrize("tool", sorted(P.TOOLS))
def test_every_protocol_has_every_tool_plugin(proto, tool):
    mod = proto.plugin(tool)
    assert mod.__name__ == f"fap_py.{P.TOOLS[tool]}.{proto.name}"


def test_one_spelling_per_protocol():
    seen: List[str] = []
    for p in P.PROTOCOLS:
        seen += [p.name, *p.aliases]
    assert len(seen) == len(set(seen))
    assert P.get("execasync").name == "exec"   # the alias of old configs, never printed


def _literal_names(node: ast.AST, spellings: Set[str]) -> List[str]:
    return [e.value for e in getattr(node, "elts", getattr(node, "keys", []))
            if isinstance(e, ast.Constant) and e.value in spellings]


def protocol_literal_findings(path: pathlib.Path) -> List[str]:
    """Switches on a protocol name and lists of protocol names in one source file."""
    spellings = _spellings()
    tree = ast.parse(path.read_text(), str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            for s in sides:
                if isinstance(s, ast.Constant) and s.value in spellings:
                    out.append(f"{path}:{node.lineno}: compares with protocol name {s.value!r}")
                if isinstance(s, (ast.Tuple, ast.List, ast.Set)) and _literal_names(s, spellings):
                    out.append(f"{path}:{node.lineno}: tests membership in protocol names")
        elif isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)):
            found = _literal_names(node, spellings)
            if len(found) >= 2 or (isinstance(node, ast.Dict) and found):
                out.append(f"{path}:{node.lineno}: lists protocol names {found}")
        elif isinstance(node, ast.match_case) and isinstance(node.pattern, ast.MatchValue) \
                and isinstance(node.pattern.value, ast.Constant) and node.pattern.value.value in spellings:
            out.append(f"{path}:{node.lineno}: matches protocol name {node.pattern.value.value!r}")
    return out


def _retyped_numbers() -> Set[str]:
    """The numbers a tool must read from the table: default baud, top node addresses and
    broadcast addresses. 0 and 255 are every byte's bounds and numbers under 100 are too
    common to tell from a limit, except a protocol's top address (FAP's 31)."""
    maxes = {p.node_max for p in P.PROTOCOLS}
    nums = {p.default_baud for p in P.PROTOCOLS} | maxes
    nums |= {p.broadcast for p in P.PROTOCOLS if p.broadcast is not None}
    return {str(n) for n in nums if n not in (0, 255) and (n >= 100 or n in maxes)}


def retyped_limit_findings(path: pathlib.Path) -> List[str]:
    """Decimal literals equal to a protocol's top address, broadcast address or default baud
    (hex masks such as 0xFF are bytes, not limits, and pass; so does an exponent: 2**31)."""
    nums = _retyped_numbers()
    out = []
    prev = None
    for tok in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
        if tok.type == tokenize.NUMBER and tok.string in nums and not (prev and prev.string in ("**", "<<")):
            out.append(f"{path}:{tok.start[0]}: re-typed protocol number {tok.string}")
        if tok.type not in (tokenize.NL, tokenize.COMMENT):
            prev = tok
    return out


def test_tool_files_carry_no_protocol_literal():
    findings = [f for path in tool_files() for f in protocol_literal_findings(path)]
    assert not findings, "\n".join(findings)


def test_tool_files_carry_no_retyped_limit():
    findings = [f for path in tool_files() for f in retyped_limit_findings(path)]
    assert not findings, "\n".join(findings)


def test_the_guards_catch_what_they_guard(tmp_path):
    """The two scanners above find a switch, a list and a re-typed limit (so a pass means something)."""
    bad = tmp_path / "bad.py"
    bad.write_text('if p == "exec":\n    pass\nPROTOS = ("fap", "g485")\nMAX = 126\nBAUD = 115200\nMASK = 0xFF\nBIG = 2**31\nID = 31\n')
    assert len(protocol_literal_findings(bad)) == 2
    assert [f.rsplit(" ", 1)[1] for f in retyped_limit_findings(bad)] == ["126", "115200", "31"]
