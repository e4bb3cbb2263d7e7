#!/usr/bin/env bash
# CI: branch coverage of the fap doctor room (issue 36: >= 95 %), measured on
# the installed package by its own tests; the figure is printed in CI's log.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
. .venv/bin/activate
python -c 'import coverage' 2>/dev/null || pip install -q 'coverage>=7'
mkdir -p build/coverage
cd build/coverage            # outside the source tree: the installed fap_py is measured
export COVERAGE_FILE=$PWD/.coverage
rm -f "$COVERAGE_FILE"
coverage run --branch --include='*/site-packages/fap_py/doctor/*,*/site-packages/fap_py/commands/doctor.py' \
  -m pytest -q -p no:cacheprovider ../../tests/python/doctor
coverage report --fail-under=95 | tail -n 15
echo "coverage: doctor room $(coverage report --format=total)% of branches and lines (>= 95 %) in $(( $(date +%s) - start )) s"
