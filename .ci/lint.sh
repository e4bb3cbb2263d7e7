#!/usr/bin/env bash
# CI: type check (mypy), lint (ruff) and C static analysis (cppcheck).
# Configuration: pyproject.toml [tool.mypy] / [tool.ruff]; .ci/cppcheck-suppressions.txt.
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive
start=$(date +%s)

if [ -f .venv/bin/activate ]; then . .venv/bin/activate; fi
python3 -m pip install -q 'mypy>=1.8' 'ruff>=0.4' >/dev/null   # the [lint] extra, without rebuilding fap_py
command -v cppcheck >/dev/null || { apt-get update -q && apt-get install -y -q cppcheck; }

echo "== mypy (fap_py)"
mypy

echo "== ruff check (fap_py tests bench examples)"
ruff check fap_py tests bench examples

echo "== cppcheck (csrc)"
cppcheck --enable=warning,style,performance,portability --std=c11 --inline-suppr \
  --suppressions-list=.ci/cppcheck-suppressions.txt --error-exitcode=1 --quiet -j2 \
  -Iinclude -Icsrc csrc

echo "lint: mypy, ruff and cppcheck passed in $(( $(date +%s) - start )) s"
