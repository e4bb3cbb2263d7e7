#!/usr/bin/env bash
# CI: short fault soak (docs/reliability.md). FAP and exec async, 30 s each:
# master + 3 slave processes on the paced virtual bus (115200) with bit
# errors and drops, a slave killed and restarted, the master's port
# disconnected and back. Fails on any corrupted or duplicated delivery, a
# stale exec reply, or a handler run twice (other than the documented
# SeqNo-0 retry). mikroC / G485: the undetected-corruption rate is printed.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -d .venv ] || python3 -m venv .venv
. .venv/bin/activate
python -c 'import fap_py' 2>/dev/null || pip install -q '.[test]'
start=$(date +%s)
out=build-soak
mkdir -p "$out"
rc=0
fap soak --protocol all --seconds "${SOAK_SECONDS:-30}" --slaves 3 --check8-seconds 5 --json \
  > "$out/soak.jsonl" || rc=$?
python3 - "$out/soak.jsonl" <<'PY'
import json, sys
for line in open(sys.argv[1]):
    r = json.loads(line)
    p = r["protocol"]
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
        print(f"soak {p}: {r['frames']} frames at bit error rate {r['bit_error_rate']}: "
              f"{r['damaged_on_wire']} damaged, {r['damage_undetected']} passed the 8-bit check "
              f"({r['undetected_per_damaged_frame']} per damaged frame)")
PY
if [ $rc -ne 0 ]; then
  echo "soak.sh: FAILED (corrupted, duplicated or stale delivery; $out/soak.jsonl)" >&2
  exit 1
fi
echo "soak.sh: OK, no corrupted or duplicated delivery, in $(( $(date +%s) - start ))s"
