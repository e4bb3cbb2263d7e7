"""`fap demo`: the first thing a new user runs. Fast, exit 0, a readable transcript."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest


@pytest.mark.parametrize("extra", [[], ["--paced"]])
def test_fap_demo_runs_and_tells_the_story(extra) -> None:
    # -I: the installed package, not the source tree in the cwd
    proc = subprocess.run([sys.executable, "-I", "-m", "fap_py", "demo", *extra],
                          capture_output=True, text=True, timeout=60)
    out = proc.stdout
    assert proc.returncode == 0, proc.stderr + out
    assert "MISMATCH" not in out and proc.stderr == ""
    for needle in ("master    -> slave 3", "slave 3   <- master", "slave 12  -> slave 3",
                   "1024 bytes", "slave 7   leaves the bus",
                   "slave 7 missed DATA_DONE -> inactive",
                   "slave 7 answered QUERY_ID -> active; active slaves: [3, 7, 12]",
                   "frames tx", "done: 3 slaves active [3, 7, 12]"):
        assert needle in out, f"{needle!r} missing from:\n{out}"
    assert len(re.findall(r"\[ok\]", out)) == 9
    # the stats table: one row per node, numbers in every column
    rows = [line for line in out.splitlines()
            if re.match(r"^(master|slave \d+)\s+\d+(\s+\d+){8}$", line)]
    assert len(rows) == 4


def test_fap_demo_is_listed_in_help() -> None:
    out = subprocess.run([sys.executable, "-I", "-m", "fap_py", "--help"],
                         capture_output=True, text=True, check=True).stdout
    assert "demo" in out
