"""`fap demo`: the first thing a new user runs. Exit 0, a readable summary, unpaced
and paced (the live view and its details: tests/python/cli/test_demo.py)."""
from __future__ import annotations

import re
import subprocess
import sys

import pytest


@pytest.mark.parametrize("extra", [[], ["--paced"]])
def test_fap_demo_runs_and_tells_the_story(extra) -> None:
    # -I: the installed package, not the source tree in the cwd
    proc = subprocess.run([sys.executable, "-I", "-m", "fap_py", "demo", "--duration", "1.5",
                           *extra], capture_output=True, text=True, timeout=60)
    out = proc.stdout
    assert proc.returncode == 0, proc.stderr + out
    assert proc.stderr == ""
    for needle in ("slave 3 active (answered QUERY_ID)", "slave 12 active (answered QUERY_ID)",
                   "frames tx", "(of 3, 7, 12)",
                   "paced" if extra else "unpaced"):
        assert needle in out, f"{needle!r} missing from:\n{out}"
    # the stats table: one row per node, numbers in every column
    rows = [line for line in out.splitlines()
            if re.match(r"^(master|slave \d+)\s+\d+(\s+\d+){8}$", line)]
    assert len(rows) == 4


def test_fap_demo_is_listed_in_help() -> None:
    out = subprocess.run([sys.executable, "-I", "-m", "fap_py", "--help"],
                         capture_output=True, text=True, check=True).stdout
    assert "demo" in out
