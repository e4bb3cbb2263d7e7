#!/usr/bin/env bash
# CI: leak checks over open/close cycles of every handle kind.
#  1. C under LeakSanitizer (ASan build): port, vbus, FAP handles (master,
#     slave, classic API), exec master/slave, mikroC contexts; fds and
#     threads must come back (tests/c/hostile/test_cycles.c).
#  2. The same program under valgrind --leak-check=full (plain build).
#  3. Python: tests/soak/py_leak_cycles.py (RSS, fds, threads stay flat).
set -euo pipefail
cd "$(dirname "$0")/.."
export DEBIAN_FRONTEND=noninteractive
command -v valgrind >/dev/null || { apt-get update -q && apt-get install -y -q valgrind; }
[ -d .venv ] || python3 -m venv .venv
. .venv/bin/activate
python -c 'import fap_py, mesonbuild' 2>/dev/null || pip install -q '.[test]'
start=$(date +%s)
t=tests/c/hostile/test_hostile_cycles
meson setup build-leak-asan --reconfigure --werror -Db_sanitize=address -Db_lundef=false \
  -Dpython=false -Dpytest=false >/dev/null
meson compile -C build-leak-asan "$t" >/dev/null
CYCLES=100 ASAN_OPTIONS=detect_leaks=1:halt_on_error=1 "build-leak-asan/$t" | tail -2
meson setup build-leak-vg --reconfigure --werror -Dpython=false -Dpytest=false >/dev/null
meson compile -C build-leak-vg "$t" >/dev/null
CYCLES=5 valgrind -q --leak-check=full --show-leak-kinds=definite,indirect \
  --errors-for-leak-kinds=definite,indirect --error-exitcode=9 "build-leak-vg/$t" | tail -2
python tests/soak/py_leak_cycles.py --cycles 300
echo "leak.sh: OK, no leak (LeakSanitizer, valgrind, Python cycles) in $(( $(date +%s) - start ))s"
