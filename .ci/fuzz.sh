#!/usr/bin/env bash
# CI: fuzz smoke. Every libFuzzer target (clang, -fsanitize=fuzzer,address,
# undefined) and the G485 parser fuzzer run ~20 s each from corpora seeded
# by the vectors; the hypothesis properties of the G485 parser run once.
# The long campaign: tests/fuzz/run.sh --seconds N (docs/reliability.md).
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive
if ! command -v clang >/dev/null || ! ls /usr/lib/llvm-*/lib/clang/*/lib/linux/libclang_rt.fuzzer-x86_64.a >/dev/null 2>&1; then
  apt-get update -q && apt-get install -y -q clang libclang-rt-14-dev
fi
[ -d .venv ] || python3 -m venv .venv
. .venv/bin/activate
python -c 'import fap_py' 2>/dev/null || pip install -q '.[test]'
python -c 'import hypothesis' 2>/dev/null || pip install -q 'hypothesis>=6'
start=$(date +%s)
tests/fuzz/run.sh --seconds "${FUZZ_SECONDS:-20}"
# from outside the tree: the source fap_py/ (no compiled extension) must not shadow the installed one
(root=$PWD; cd /tmp && CI=true python -m pytest -q -p no:cacheprovider "$root/tests/fuzz/test_g485_fuzz.py")
(root=$PWD; cd /tmp && CI=true python -m pytest -q -p no:cacheprovider "$root/tests/fuzz/test_monitor_fuzz.py")
(root=$PWD; cd /tmp && CI=true python -m pytest -q -p no:cacheprovider "$root/tests/fuzz/test_bridge_config_fuzz.py")
echo "fuzz.sh: OK, fuzz smoke passed in $(( $(date +%s) - start ))s"
