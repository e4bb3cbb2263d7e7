#!/usr/bin/env bash
# Fuzz campaign: build the libFuzzer targets, seed their corpora from the
# vectors, run each target (and the Python fuzzers) for N seconds.
#   tests/fuzz/run.sh --seconds N [--out DIR] [TARGET...]
# Targets (default: all, found in tests/fuzz/, not listed here): every
# fuzz_<name>.c (libFuzzer) and every <name>_fuzz.py but test_* (target
# <name>; it takes --seconds, --corpus and --json). Corpora grow in DIR/corpus/<target>
# (kept between runs); a crashing input is saved as DIR/crash-<target>-*.
# Prints executions per target; exit 1 if any target found a failure.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
seconds=20
out="$root/build-fuzz"
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    *) targets+=("$1"); shift ;;
  esac
done
if [ ${#targets[@]} -eq 0 ]; then
  for f in "$root"/tests/fuzz/fuzz_*.c; do t=$(basename "$f"); targets+=("${t%.c}"); done
  for f in "$root"/tests/fuzz/*_fuzz.py; do   # but the pytest files test_*
    t=$(basename "$f"); case "$t" in test_*) continue ;; esac; targets+=("${t%_fuzz.py}")
  done
fi
"$root/tests/fuzz/build.sh" "$out"
python3 "$root/tests/fuzz/seed_corpus.py" "$out/corpus"
python="${PYTHON:-python3}"
[ -x "$root/.venv/bin/python" ] && python="$root/.venv/bin/python"
fail=0
summary=()
for t in "${targets[@]}"; do
  log="$out/$t.log"
  if [ -e "$root/tests/fuzz/${t}_fuzz.py" ]; then
    if nice "$python" "$root/tests/fuzz/${t}_fuzz.py" --seconds "$seconds" --corpus "$out/corpus/$t" --json >"$log" 2>&1; then
      execs=$("$python" -c 'import json,sys; print(json.loads(open(sys.argv[1]).read().splitlines()[-1])["executions"])' "$log")
    else
      fail=1; execs="FAILED"; tail -20 "$log" >&2
    fi
  else
    mkdir -p "$out/corpus/$t"
    if nice "$out/$t" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=1024 -print_final_stats=1 \
         -artifact_prefix="$out/crash-$t-" "$out/corpus/$t" >"$log" 2>&1; then
      execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
    else
      fail=1; execs="FAILED"; grep -E "ERROR|property failed|runtime error|SUMMARY" "$log" | head -10 >&2
    fi
  fi
  summary+=("$t $execs")
  printf 'fuzz: %-18s %s executions in %ss\n' "$t" "$execs" "$seconds"
done
if [ $fail -ne 0 ]; then
  echo "fuzz: FAILED (logs and crash inputs in $out)" >&2
  exit 1
fi
echo "fuzz: ${#targets[@]} targets, ${seconds}s each, no crash, leak, hang or property failure"
