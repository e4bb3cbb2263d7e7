#!/usr/bin/env bash
# CI: `python -m bench --quick` as a smoke test. It asserts that every
# benchmark runs and produces its JSON, table and plots - never a speed -
# and that a run adds nothing to git (results go to --out; by default to
# $XDG_CACHE_HOME/fap-bench, outside the tree). CI keeps build/bench-smoke.
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive
start=$(date +%s)

# The C peer (libmodbus) is part of what it runs; the Python peers only of the
# full run (installed all the same, so a full `python -m bench` from this venv has them).
if ! pkg-config --exists libmodbus; then
  apt-get update -q && apt-get install -y -q -o DPkg::Lock::Timeout=600 libmodbus-dev
fi
[ -d .venv ] || python3 -m venv .venv
. .venv/bin/activate
python -c 'import matplotlib, pymodbus, minimalmodbus, dynamixel_sdk' 2>/dev/null || pip install -q '.[test,bench]'
python -c 'import fap_py._native' 2>/dev/null || pip install -q .
meson setup build --reconfigure >/dev/null
meson compile -C build bench/wire/bench_wire bench/fap_py/bench_fapx_c >/dev/null

out=build/bench-smoke
rm -rf "$out"
before=$(git status --porcelain 2>/dev/null || true)
python -m bench --quick --out "$out"
after=$(git status --porcelain 2>/dev/null || true)
[ "$before" = "$after" ] || { echo "bench.sh: the run changed the source tree:"; diff <(echo "$before") <(echo "$after"); exit 1; }
python - "$out" <<'PY'
import json, sys
from pathlib import Path
out = Path(sys.argv[1])
res = json.loads((out / "results.json").read_text())
for f in ("table.md", "efficiency.png", "turnaround.png", "cpu.png", "scaling.png"):
    assert (out / f).stat().st_size > 0, f"{f} missing"
assert not res["missing"], f"peers missing in CI: {res['missing']}"
# --quick leaves out the Python peers on purpose: recorded as skipped, not missing
assert all(why.startswith("not run in --quick") for why in res["skipped"].values()), res["skipped"]
cells = [(b, k, r) for b, rows in res["paced"].items() for k, r in rows.items()]
cells += [("unpaced", k, r) for k, r in res["unpaced"].items()]
bad = [f"{k} at {b}" for b, k, r in cells if "error" in r or r["rate"]["median"] <= 0]
assert not bad, f"benchmarks that did not run: {bad}"
assert res["scale"] and res.get("python"), "scale or Python overhead missing"
print(f"bench smoke: {len(cells)} cells, all ran; measuring {res['wall_s']:.0f} s")
PY
echo "bench.sh: OK: python -m bench --quick (the smoke run) ran every benchmark it runs in $(( $(date +%s) - start )) s"
