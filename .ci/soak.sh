#!/usr/bin/env bash
# CI: short fault soak (docs/reliability.md), every protocol of the table:
# 30 s each, 15 s for those with an 8-bit frame check (mikroC, G485; their
# plug-in's CHECK8): master + 3 slave processes on the paced virtual
# bus (115200) with bit errors and drops, a slave killed and restarted, the
# master's port disconnected and back. Fails on a crash or hang, any
# corrupted or duplicated FAP delivery, a stale exec reply, an exec handler
# run twice (other than the documented SeqNo-0 retry), or a mikroC frame
# delivered twice. mikroC / G485 corruption that passed their 8-bit checks
# is measured and printed, not failed on. Then fap serve's volume run: 10^5
# transactions of client processes through the daemon, every protocol.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -d .venv ] || python3 -m venv .venv
. .venv/bin/activate
python -c 'import fap_py' 2>/dev/null || pip install -q '.[test]'
start=$(date +%s)
out=build-soak
mkdir -p "$out"
: > "$out/soak.jsonl"
rc=0
soak() {  # protocol seconds; a hang is a failure (timeout exits 124)
  timeout --kill-after=10 "$(( ${2%.*} + 90 ))" \
    fap soak --protocol "$1" --seconds "$2" --slaves 3 --check8-seconds 3 --json \
    >> "$out/soak.jsonl" || { echo "soak.sh: fap soak --protocol $1 exited $?" >&2; rc=1; }
}
# every protocol of the table (fap_py/_protocols.py), each its plug-in's CI run:
# SOAK8_SECONDS for one with an 8-bit frame check (its plug-in's CHECK8), else SOAK_SECONDS
plan=$(python3 -c '
from fap_py import _protocols
for n in _protocols.names():
    print(n, 8 if getattr(_protocols.get(n).plugin("soak"), "CHECK8", False) else "")')
while read -r proto check8; do
  if [ -n "$check8" ]; then soak "$proto" "${SOAK8_SECONDS:-15}"; else soak "$proto" "${SOAK_SECONDS:-30}"; fi
done <<< "$plan"
# each protocol's summary, as its soak plug-in words it (report(result))
python3 - "$out/soak.jsonl" <<'PY'
import json, sys
from fap_py import _protocols
seen = set()
for line in open(sys.argv[1]):
    r = json.loads(line)
    seen.add(r["protocol"])
    report = getattr(_protocols.get(r["protocol"]).plugin("soak"), "report", None)
    for text in report(r) if report else [f"soak {r['protocol']}: ok {r.get('ok')}"]:
        print(text)
missing = set(_protocols.names()) - seen
if missing:
    sys.exit(f"soak.sh: no result for {sorted(missing)}")
PY
# the daemon under volume (docs/daemon.md, Testing): 3 client processes per case, every
# protocol, Unix socket and TCP, 10^5 transactions in all; it prints each case's rate and
# the total. From $out: `python -m pytest` in the tree would import the unbuilt sources.
(cd "$out" && FAP_SERVE_VOLUME="${FAP_SERVE_VOLUME:-100000}" timeout --kill-after=10 1500 \
  python -m pytest -q -p no:cacheprovider ../tests/python/serve/test_volume.py) \
  || { echo "soak.sh: the daemon volume run (tests/python/serve/test_volume.py) failed" >&2; rc=1; }
if [ $rc -ne 0 ]; then
  echo "soak.sh: FAILED (crash, hang, corrupted, duplicated or stale delivery; $out/soak.jsonl)" >&2
  exit 1
fi
echo "soak.sh: OK, every protocol's soak passed its verdict, in $(( $(date +%s) - start ))s"
