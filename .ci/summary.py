"""Closing lines for CI from meson's test logs.

Prints pytest's own summary (meson keeps test output to itself on success)
and then one line counting every meson test of every build given:
'N passed, N failed'. Exits 1 if anything failed or nothing ran.
"""
import json
import re
import sys
from pathlib import Path

passed = failed = 0
for build in sys.argv[1:]:
    log = Path(build) / "meson-logs" / "testlog.json"
    if not log.exists():
        continue
    for line in log.read_text().splitlines():
        entry = json.loads(line)
        result = entry.get("result")
        if result in ("OK", "EXPECTEDFAIL"):
            passed += 1
        elif result != "SKIP":
            failed += 1
        if entry.get("name", "").split(":")[-1] == "pytest":
            found = re.findall(r"^=*\s*(\d+ passed.*?)\s*=*$", entry.get("stdout", ""), re.M)
            if found:
                print(f"pytest ({build}): {found[-1]}")
            out = entry.get("stdout", "")
            if "slowest" in out:   # pytest --durations (tests/meson.build)
                rows = out.split(" durations ", 1)[1].splitlines()[1:]
                rows = [r for r in rows[:40] if re.match(r"^\d+\.\d+s ", r)]
                print(f"pytest ({build}): slowest tests\n" + "\n".join(rows[:20]))
print(f"{passed} passed, {failed} failed")
sys.exit(1 if failed or not passed else 0)
