"""The C core's layering, read from the sources (no build needed):

* no circle in csrc/'s ``#include`` graph (headers of csrc/ and include/);
* no circle between csrc/'s translation units by the functions they call
  (port.c and port_net.c used to call each other: the transport map,
  csrc/port/port_transport.c, is now the one caller of both);
* nothing outside csrc/port/ includes ``port_internal.h`` or reads a port's
  backend pointer: engines ask ``fap_port_caps``;
* Python code outside fap_py/port.py does not guess what a port string is
  with ``"://" in``: it asks ``fap_py.port.port_kind`` (the C core's
  ``fap_port_kind``).
"""
from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Dict, List, Set, Tuple

ROOT = Path(__file__).resolve().parents[2]
CSRC = ROOT / "csrc"
INCLUDE = ROOT / "include"


def _strip_c(text: str) -> str:
    """C text without comments and string literals (newlines kept)."""
    text = re.sub(r"/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    return re.sub(r'"(?:\\.|[^"\\\n])*"', '""', text)


def _c_files() -> List[Path]:
    return sorted(p for d in (CSRC, INCLUDE) for p in d.rglob("*") if p.suffix in (".c", ".h"))


def _resolve(name: str, src: Path) -> Path | None:
    """Where a quoted include lands: next to the file, under csrc/, under include/."""
    for base in (src.parent, CSRC, INCLUDE):
        cand = (base / name).resolve()
        if cand.is_file():
            return cand
    return None


def _include_graph() -> Dict[Path, Set[Path]]:
    graph: Dict[Path, Set[Path]] = {}
    for f in _c_files():
        deps = set()
        for m in re.finditer(r'(?m)^[ \t]*#[ \t]*include[ \t]*"([^"]+)"', f.read_text()):
            to = _resolve(m.group(1), f)
            if to is not None:
                deps.add(to)
        graph[f.resolve()] = deps
    return graph


def _call_graph() -> Dict[Path, Set[Path]]:
    """csrc/'s .c files, each to the files whose non-static functions it calls."""
    sources = sorted(CSRC.rglob("*.c"))
    text = {f: _strip_c(f.read_text()) for f in sources}
    defined: Dict[str, Path] = {}
    for f, t in text.items():
        for m in re.finditer(r"(?m)^(?!static\b)[A-Za-z_][\w \t*]*?\b([a-z_]\w*)\s*\([^;{]*\)\s*\{", t):
            defined.setdefault(m.group(1), f)
    return {f: {defined[c] for c in set(re.findall(r"\b([a-z_]\w*)\s*\(", t))
                if c in defined and defined[c] != f} for f, t in text.items()}


def _cycles(graph: Dict, ) -> List[Tuple[str, ...]]:
    """The strongly connected groups of more than one node (Tarjan), as sorted names."""
    index: Dict = {}
    low: Dict = {}
    stack: List = []
    found: List[Tuple[str, ...]] = []

    def name(v: object) -> str:
        return str(Path(str(v)).relative_to(ROOT)) if Path(str(v)).is_absolute() else str(v)

    def visit(v: object) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ()), key=str):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1 or v in graph.get(v, ()):
                found.append(tuple(sorted(name(g) for g in group)))

    for v in sorted(graph, key=str):
        if v not in index:
            visit(v)
    return sorted(found)


def test_walkers_find_what_they_look_for() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [("a", "b", "c")]
    inc = _include_graph()
    engine = (CSRC / "fap" / "engine.c").resolve()
    assert (CSRC / "port" / "rx_pacing.h").resolve() in inc[engine]
    calls = _call_graph()
    transport = CSRC / "port" / "port_transport.c"
    assert {CSRC / "port" / "port.c", CSRC / "port" / "port_net.c"} <= calls[transport]


def test_no_include_circle() -> None:
    assert not _cycles(_include_graph())


def test_no_circle_between_c_files_by_calls() -> None:
    assert not _cycles(_call_graph())


def test_port_internals_stay_in_the_port_layer() -> None:
    port_dir = (CSRC / "port").resolve()
    bad = []
    for f, deps in _include_graph().items():
        if port_dir in f.parents:
            continue
        bad += [f"{f.relative_to(ROOT)} includes {d.name}" for d in deps
                if d.name == "port_internal.h"]
        if f.suffix == ".c" and re.search(r"->\s*be\b|_backend\b", _strip_c(f.read_text())):
            bad.append(f"{f.relative_to(ROOT)} reads a port backend")
    assert not bad, bad


def _guesses(tree: ast.AST) -> List[int]:
    """Lines of a ``"://" in x`` / ``"://" not in x`` test."""
    lines = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Compare) and isinstance(node.left, ast.Constant)
                and node.left.value in ("://", b"://")
                and any(isinstance(op, (ast.In, ast.NotIn)) for op in node.ops)):
            lines.append(node.lineno)
    return lines


def test_python_asks_port_kind_instead_of_guessing() -> None:
    assert _guesses(ast.parse('ok = "://" in path or b"://" not in raw')) == [1, 1]
    allowed = ROOT / "fap_py" / "port.py"
    bad = [f"{f.relative_to(ROOT)}:{line}" for f in sorted((ROOT / "fap_py").rglob("*.py"))
           if f != allowed for line in _guesses(ast.parse(f.read_text(), str(f)))]
    assert not bad, f"ask fap_py.port.port_kind(path) instead: {bad}"


# The port logic and the network transport reach the line only through the
# line-level transport table (port_backend.h): termios and the tty ioctls
# are the device transport's (port_device.c) alone.
_LINE_ONLY = ("port.c", "port_config.c", "port_io.c", "port_net.c", "port_backend.h",
              "port_internal.h")
_TTY_WORDS = re.compile(
    r"#\s*include\s*<(?:termios\.h|sys/ioctl\.h|sys/file\.h)>"
    r"|\b(?:struct\s+termios|tc[gs]etattr|tcflush|tcdrain|cfmakeraw|cfset[io]speed|cfget[io]speed"
    r"|ioctl|flock|TIOC\w+|TC[IO]+FLUSH|TCSANOW|speed_t)\b")


def test_tty_calls_stay_in_the_device_transport() -> None:
    assert _TTY_WORDS.search("x = tcsetattr(fd, TCSANOW, &t);")
    assert _TTY_WORDS.search("#include <termios.h>")
    assert not _TTY_WORDS.search("p->be->set_line(p->ctx, fd, baud, 0);")
    bad = []
    for name in _LINE_ONLY:
        f = CSRC / "port" / name
        for n, line in enumerate(_strip_c(f.read_text()).splitlines(), 1):
            m = _TTY_WORDS.search(line)
            if m:
                bad.append(f"csrc/port/{name}:{n}: {m.group(0)}")
    assert not bad, f"termios and tty ioctls belong in port_device.c: {bad}"
