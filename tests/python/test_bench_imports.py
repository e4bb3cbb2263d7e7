"""bench/'s imports (issue 31): no circle between its modules, and nothing from
``tests/`` (nor pytest) or the CLI's private ``fap_py.commands._*`` modules, so
``python -m bench`` runs with only ``pip install '.[bench]'``.

The walk reads every ``bench/**/*.py`` with ``ast`` (imports inside functions
count: a lazy import is still a dependency) and maps each import to a file of
bench/ when it names one: ``bench.x.y``, ``from bench import x``, and the
programs bench puts on ``sys.path`` by file name (``import bench_g485``).
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path
from typing import Dict, Iterator, List, Optional, Set, Tuple

ROOT = Path(__file__).resolve().parents[2]


def _modules(bench: Path) -> Dict[str, Path]:
    """Dotted name -> file, for every module of the bench tree (``bench.x.y``)."""
    out = {}
    for f in sorted(bench.rglob("*.py")):
        if "results" in f.relative_to(bench).parts:
            continue
        parts = list(f.relative_to(bench.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def _imports(tree: ast.AST, here: str) -> Iterator[Tuple[str, Optional[str]]]:
    """(module, name imported from it or None) of every import statement."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, None
        elif isinstance(node, ast.ImportFrom):
            mod = node.module or ""
            if node.level:
                base = here.split(".")[:-node.level] if node.level else []
                mod = ".".join(base + ([mod] if mod else []))
            for a in node.names:
                yield mod, a.name


def _path_strings(tree: ast.AST) -> Iterator[str]:
    """String constants that name a path into tests/ (a sys.path entry)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            v = node.value
            if v == "tests" or v.startswith("tests/") or "/tests/" in v:
                yield v


def walk(bench: Path) -> Tuple[Dict[str, Set[str]], List[str]]:
    """The import graph between bench's modules and the forbidden imports found."""
    mods = _modules(bench)
    by_stem: Dict[str, str] = {}
    for name in mods:
        stem = name.rsplit(".", 1)[-1]
        if stem not in sys.stdlib_module_names and name.count(".") >= 1:
            by_stem.setdefault(stem, name)
    test_stems = {f.stem for f in (bench.parent / "tests").rglob("*.py")} - set(by_stem) \
        - set(sys.stdlib_module_names) if (bench.parent / "tests").is_dir() else set()
    graph: Dict[str, Set[str]] = {name: set() for name in mods}
    bad: List[str] = []
    for name, f in mods.items():
        tree = ast.parse(f.read_text(), str(f))
        where = str(f.relative_to(bench.parent))
        for v in _path_strings(tree):
            bad.append(f"{where}: a path into tests/: {v!r}")
        for mod, what in _imports(tree, name):
            top = mod.split(".")[0]
            full = f"{mod}.{what}" if what else mod
            if top in ("tests", "pytest", "_pytest") or top in test_stems:
                bad.append(f"{where}: imports {full} (from the tests)")
            if full.startswith("fap_py.commands._") or (
                    mod == "fap_py.commands" and what and what.startswith("_")):
                bad.append(f"{where}: imports {full} (a private module of the CLI)")
            target = None
            if what and f"{mod}.{what}" in mods:
                target = f"{mod}.{what}"
            elif mod in mods:
                target = mod
            elif top in by_stem and mod == top:
                target = by_stem[top]
            if target and target != name and target != "bench":
                graph[name].add(target)
    return graph, bad


def cycles(graph: Dict[str, Set[str]]) -> List[List[str]]:
    """Every import circle (one per strongly connected group of 2+ modules)."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    on: Set[str] = set()
    out: List[List[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_bench_has_no_import_circle_and_imports_no_tests() -> None:
    graph, bad = walk(ROOT / "bench")
    assert "bench.__main__" in graph and graph["bench.__main__"], "the walk found no imports"
    assert not cycles(graph), cycles(graph)
    assert not bad, "\n".join(bad)


def test_the_walk_finds_a_circle_and_a_tests_import(tmp_path: Path) -> None:
    """The checker itself: the shapes issue 31 found (net.py <-> __main__, a
    program pair on sys.path, the tests' helpers, the CLI's private Progress)."""
    b = tmp_path / "bench"
    (b / "g485").mkdir(parents=True)
    (b / "__init__.py").write_text("")
    (b / "__main__.py").write_text("from bench import net\nfrom fap_py.commands._node import Progress\n")
    (b / "net.py").write_text("def f():\n    from bench.__main__ import pct\n"
                              "    sys.path.insert(0, str(ROOT / 'tests' / 'python'))\n"
                              "    from net_helpers import Ser2net\n")
    (b / "g485" / "paired.py").write_text("import bench_g485 as g\n")
    (b / "g485" / "bench_g485.py").write_text("def p():\n    import paired\n")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "net_helpers.py").write_text("import pytest\n")
    graph, bad = walk(b)
    assert cycles(graph) == [["bench.__main__", "bench.net"], ["bench.g485.bench_g485", "bench.g485.paired"]]
    assert any("fap_py.commands._node" in m for m in bad)
    assert any("net_helpers" in m for m in bad) and any("'tests'" in m for m in bad)
