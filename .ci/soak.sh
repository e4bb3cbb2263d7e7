#!/usr/bin/env bash
# CI: short fault soak (docs/reliability.md). FAP and exec async 30 s each,
# mikroC and G485 15 s each: master + 3 slave processes on the paced virtual
# bus (115200) with bit errors and drops, a slave killed and restarted, the
# master's port disconnected and back. Fails on a crash or hang, any
# corrupted or duplicated FAP delivery, a stale exec reply, an exec handler
# run twice (other than the documented SeqNo-0 retry), or a mikroC frame
# delivered twice. mikroC / G485 corruption that passed their 8-bit checks
# is measured and printed, not failed on.
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
soak fap "${SOAK_SECONDS:-30}"
soak exec "${SOAK_SECONDS:-30}"
soak mikroc "${SOAK8_SECONDS:-15}"
soak g485 "${SOAK8_SECONDS:-15}"
python3 - "$out/soak.jsonl" <<'PY'
import json, sys
seen = set()
for line in open(sys.argv[1]):
    r = json.loads(line)
    p = r["protocol"]
    seen.add(p)
    if p == "fap":
        a, b = r["master_to_slaves"], r["slaves_to_master"]
        print(f"soak fap: m->s sent {a['sent']} intact {a['delivered_intact']} corrupted {a['corrupted']} "
              f"duplicated {a['duplicated']} lost {a['lost']} (counters {a['loss_counters']}); "
              f"s->m sent {b['sent']} intact {b['delivered_intact']} corrupted {b['corrupted']} "
              f"duplicated {b['duplicated']} lost {b['lost']}; recovery {r['recovery_s']}")
    elif p == "exec":
        print(f"soak exec: {r['transactions']} transactions, intact {r['replies_intact']}, corrupted "
              f"{r['replies_corrupted']}, stale {r['stale_replies']}, handler twice {r['duplicated']} "
              f"(+{r['duplicated_seq0_documented']} documented SeqNo 0), failed {r['failed']}, "
              f"recovery {r['recovery_s']}")
    else:
        if p == "mikroc":
            a, b = r["master_to_slaves"], r["slaves_to_master"]
            print(f"soak mikroc: bus BER {r['faults']['bit_error_rate']}/byte, {r['faults']['bus_bit_errors']} bit errors; "
                  f"m->s sent {a['sent']} intact {a['delivered_intact']} corrupted-undetected "
                  f"{a['corrupted_undetected']} duplicated {a['duplicated']} lost {a['lost']}; "
                  f"s->m intact {b['delivered_intact']} corrupted-undetected "
                  f"{b['corrupted_undetected'] + b['from_wrong_node']} duplicated {b['duplicated']} "
                  f"lost {b['lost']}; recovery {r['recovery_s']}")
        else:
            print(f"soak g485: bus BER {r['faults']['bit_error_rate']}/byte, {r['faults']['bus_bit_errors']} bit errors; "
                  f"{r['sent']} write+read-back cycles, intact {r['delivered_intact']}, corrupted-undetected "
                  f"{r['corrupted_undetected']}, stale {r['stale_read']}, lost {r['lost']} (failed {r['failed']}); "
                  f"recovery {r['recovery_s']}")
        print(f"soak {p}: UNDETECTED CORRUPTION RATE on the bus {r['undetected_corruption_rate']} per message")
        c = r["channel"]
        print(f"soak {p} channel: {c['frames']} frames at bit error rate {c['bit_error_rate']}: "
              f"{c['damaged_on_wire']} damaged, {c['damage_undetected']} passed the 8-bit check "
              f"({c['undetected_per_damaged_frame']} per damaged frame)")
missing = {"fap", "exec", "mikroc", "g485"} - seen
if missing:
    sys.exit(f"soak.sh: no result for {sorted(missing)}")
PY
if [ $rc -ne 0 ]; then
  echo "soak.sh: FAILED (crash, hang, corrupted, duplicated or stale delivery; $out/soak.jsonl)" >&2
  exit 1
fi
echo "soak.sh: OK, no corrupted or duplicated FAP / exec delivery, no mikroC duplicate, in $(( $(date +%s) - start ))s"
