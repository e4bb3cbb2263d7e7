"""The C side's per-protocol lists are made from one table (issue 31), and
docs/architecture.md's recipe names every shared file a new protocol edits.

- A build, test or CI file of the C side that names the built-in protocols
  side by side (``fap``, ``exec``, ``mikroc`` within a few lines of code, comments
  aside) is a hand-kept per-protocol list: it must be one the recipe names
  ("Adding a protocol"), so a new list cannot appear unnoticed.
- The lists that are derived stay derived: the codec rows, the fuzz targets
  and their seeds, the exported symbols, the man3 sources, the installed
  package's exclusions, the soak report.
"""
from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NAMES = ("fap", "exec", "mikroc")
WINDOW = 3            # lines: a list written one item per line still counts

# The C side's build, test and CI files (the Python tool rooms have their own
# guard, tests/python/test_protocol_rooms.py; bench/ its own suites).
SCOPE = re.compile(r"""^(
    (.*/)?meson\.build | meson\.options | pyproject\.toml |
    \.ci/.* | tools/.* | csrc/.* | include/.* | man/meson\.build |
    fap_py/cdef/.* |
    tests/(c|fuzz|install|man|soak|qemu)/.*
)$""", re.X)
SKIP = re.compile(r"\.(md|json|txt|pcap|png|svg|row)$|(^|/)README$")

# The shared files the recipe allows to list the protocols, and why. Each must
# be named in docs/architecture.md's "Adding a protocol".
ALLOWED = {
    "meson.build": "the components list: the one table of the C side",
    "pyproject.toml": "the package's keywords (optional)",
    # spot checks of each built-in protocol, not lists a new protocol edits
    "tests/c/port/test_rx_pacing.c": "a test per protocol's missing-bytes rule",
    "tests/man/test_man.sh": "a rendered page of each API checked",
}


def _tracked() -> list:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [f for f in out.stdout.split() if SCOPE.match(f) and not SKIP.search(f)]


def _code(path: Path) -> list:
    """The file's lines with comments blanked (C, shell, meson, Python, TOML)."""
    text = path.read_text(encoding="utf-8", errors="replace")
    if path.suffix in (".c", ".h", ".in", ".map", ".cdef"):
        text = re.sub(r"/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S)
        text = re.sub(r"//[^\n]*", "", text)
    else:
        text = re.sub(r"(?m)(^|\s)#[^\n]*", r"\1", text)
    return text.splitlines()


# a name as a word or a part of a name between underscores or slashes
# (fuzz_fap_decoder, csrc/mikroc/, execasync); not fap_py's own name
_WORD = {n: re.compile(r"(?<![a-z0-9.-])" + n + r"(?:async)?(?![a-z0-9])(?!_py)") for n in NAMES}


def protocol_lists(files) -> dict:
    """{file: first line} of each file naming every built-in protocol within WINDOW lines."""
    found = {}
    for f in files:
        p = ROOT / f
        if not p.is_file():
            continue
        lines = _code(p)
        for i in range(len(lines)):
            window = " ".join(lines[i:i + WINDOW])
            if all(w.search(window) for w in _WORD.values()):
                found[f] = i + 1
                break
    return found


def _recipe() -> str:
    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    start = doc.index("### Adding a protocol")
    end = doc.index("\n### ", start + 1)
    return doc[start:end]


def test_the_detector_finds_a_list(tmp_path, monkeypatch):
    """The check would catch a new hand-kept list (and ignores one in a comment)."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "x.sh").write_text("for p in fap exec \\\n    mikroc; do :; done\n")
    (tmp_path / "y.c").write_text("/* fap, exec, mikroc */\nint x;\n")
    (tmp_path / "z.py").write_text("# fap exec mikroc\nX = 1\n")
    (tmp_path / "w.sh").write_text("t=(fuzz_fap_decoder fuzz_exec_pack\n  fuzz_mikroc)\n")
    (tmp_path / "v.sh").write_text("ls csrc/fap/*.c csrc/execasync/*.c csrc/mikroc/*.c\n")
    (tmp_path / "u.sh").write_text("import fap_py; exec_fn(); mikroc\n")
    assert protocol_lists(["x.sh", "y.c", "z.py", "w.sh", "v.sh", "u.sh"]) == \
        {"x.sh": 1, "w.sh": 1, "v.sh": 1}


def test_every_shared_protocol_list_is_in_the_recipe():
    found = protocol_lists(_tracked())
    unnamed = {f: line for f, line in found.items() if f not in ALLOWED}
    assert not unnamed, (
        f"per-protocol lists not made from the components list or the protocol table: {unnamed}; "
        "derive them, or name the file in docs/architecture.md's recipe and in ALLOWED")
    recipe = _recipe()
    for f in ALLOWED:
        assert f"`{f}`" in recipe, f"docs/architecture.md's recipe does not name {f}"


def test_the_recipe_counts_its_shared_edits():
    """The recipe says how many shared files a C protocol edits, and it is at most 2."""
    m = re.search(r"(\d+) edits? to shared files", _recipe())
    assert m and int(m.group(1)) <= 2


# ---- the derived lists stay derived ----

def test_codec_rows_are_generated():
    table = (ROOT / "csrc" / "common" / "codec_table.c").read_text()
    code = "\n".join(_code(ROOT / "csrc" / "common" / "codec_table.c"))
    assert "lf_codec_rows" in table
    for name in NAMES + ("execasync",):
        assert f'"{name}"' not in code, f"csrc/common/codec_table.c spells the row {name}"
    # each alias is declared by its own row
    assert '"execasync"' in (ROOT / "csrc" / "execasync" / "codec_table.c").read_text()
    assert "codec_table.c" in (ROOT / "csrc" / "meson.build").read_text()
    assert "CHECK_EQ(n, 3)" not in (ROOT / "tests" / "c" / "codec" / "test_codec_table.c").read_text()


def test_exports_come_from_the_components():
    tmpl = (ROOT / "csrc" / "libfap.map.in").read_text()
    assert "@GLOBALS@" in tmpl and "exec*" not in tmpl
    assert not (ROOT / "csrc" / "libfap.map").exists()
    for comp in ("common", "execasync", "mikroc"):
        assert (ROOT / "csrc" / comp / "exports.map").is_file()


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod                    # dataclasses look their module up
    try:
        spec.loader.exec_module(mod)
    finally:
        del sys.modules[name]
    return mod


def test_fuzz_targets_and_seeds_are_found():
    seed = _load(ROOT / "tests" / "fuzz" / "seed_corpus.py", "seed_corpus_under_test")
    targets = seed.targets()
    assert "fuzz_codec_table" in targets and "g485" in targets
    assert not [t for t in targets if t.startswith("test_")]
    for t in targets:                          # each target's seeds are its own file
        if (ROOT / "tests" / "fuzz" / "seeds" / f"{t}.py").is_file():
            assert seed.seeds_of(t), t
    assert not seed.seeds_of("fuzz_no_such_target")   # no seeds file: an empty corpus
    # every row that names its vectors seeds the table target
    rows = sorted(p.stem for p in (ROOT / "tests" / "c" / "codec" / "rows").glob("*.row"))
    heads = {s.split(b"\0", 1)[0].decode() for s in seed.seeds_of("fuzz_codec_table")}
    assert heads == set(rows)
    for script in ("build.sh", "run.sh"):
        text = (ROOT / "tests" / "fuzz" / script).read_text()
        assert "fuzz_mikroc" not in text and "csrc/execasync" not in text, script


def test_installed_exclusions_cover_every_folder():
    """fap_py/meson.build's __pycache__ exclusions, computed as meson computes them,
    name every folder of the package."""
    build = (ROOT / "fap_py" / "meson.build").read_text()
    assert "'commands/__pycache__'" not in build          # no hand list
    snippet = re.search(r"run_command\(py, '-c', '''(.*?)'''", build, re.S).group(1)
    out = subprocess.run([sys.executable, "-c", snippet, str(ROOT / "fap_py")],
                         capture_output=True, text=True, check=True).stdout.split()
    folders = {str(p.relative_to(ROOT / "fap_py")) for p in (ROOT / "fap_py").rglob("*")
               if p.is_dir() and "__pycache__" not in p.parts}
    want = {"__pycache__"} | {f"{d}/__pycache__" for d in folders}
    assert want <= set(out), sorted(want - set(out))


def test_man3_takes_a_components_own_entries(tmp_path):
    gen = _load(ROOT / "tools" / "gen_man3.py", "gen_man3_under_test")
    header = tmp_path / "toy.h"
    header.write_text("/* Do the toy thing. */\nint toy_do(int x);\n")
    main = tmp_path / "functions.txt"
    main.write_text("%% date: 2026-01-01\n")
    own = tmp_path / "toy.txt"
    own.write_text("== toy_do\ndo the toy thing\n-- return\n0.\n")
    out = tmp_path / "man3"
    assert gen.main([str(main), str(out), "--version=1", f"--source={own}", str(header)]) == 0
    assert "toy_do" in (out / "toy_do.3").read_text()
    with pytest.raises(SystemExit):            # the same function described twice
        gen.main([str(own), str(out), f"--source={own}", str(header)])


def test_soak_script_names_no_protocol():
    text = "\n".join(_code(ROOT / ".ci" / "soak.sh")).replace("fap soak", "")
    for name in NAMES + ("g485",):
        assert not re.search(r"(?<![\w.-])" + name + r"(?![\w])", text, re.I), name
    from fap_py import _protocols
    for name in _protocols.names():
        assert callable(getattr(_protocols.get(name).plugin("soak"), "report", None)), name
