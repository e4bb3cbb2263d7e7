#!/usr/bin/env python3
"""Write the seed corpora of the fuzz targets from the byte-exact vectors.

    seed_corpus.py OUT_DIR      -> OUT_DIR/<target>/seed-*

The targets are found, not listed: every tests/fuzz/fuzz_<name>.c and every
<name>_fuzz.py (but the pytest files test_*). A target's seeds come from its own module,
tests/fuzz/seeds/<target>.py, whose seeds(root) returns the inputs (in the
target's input format, see the comment at the top of its source); a target
without one starts from an empty corpus."""
import hashlib
import importlib.util
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]
HERE = ROOT / "tests" / "fuzz"


def targets() -> list:
    return sorted([p.stem for p in HERE.glob("fuzz_*.c")] +
                  [p.name[:-len("_fuzz.py")] for p in HERE.glob("*_fuzz.py")
                   if not p.name.startswith("test_")])


def seeds_of(target: str) -> list:
    path = HERE / "seeds" / f"{target}.py"
    if not path.exists():
        return []
    spec = importlib.util.spec_from_file_location(f"fuzz_seeds_{target}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(path.parent))          # seeds/_vectors.py, shared helpers
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(path.parent))
    return list(mod.seeds(ROOT))


def write(out: pathlib.Path, target: str, seeds: list) -> int:
    d = out / target
    d.mkdir(parents=True, exist_ok=True)
    for s in seeds:
        (d / ("seed-" + hashlib.sha1(s).hexdigest()[:16])).write_bytes(s)
    return len(seeds)


def main() -> int:
    out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "build-fuzz/corpus")
    n = sum(write(out, t, seeds_of(t)) for t in targets())
    print(f"seed_corpus: {n} seeds in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
