"""What ``fap monitor`` says (issue 25, defects 9 and 10): no "locked on"
without a frame, stdin times from the first record, garbage in bounded
lines, a bad capture named."""
from __future__ import annotations

import random

from monitor_helpers import run_fap, stream

from fap_py.monitor.decoders import GARBAGE_MAX


def test_auto_without_a_frame_does_not_claim_a_lock(tmp_path):
    f = tmp_path / "noise.bin"
    f.write_bytes(bytes(5000))
    res = run_fap("monitor", "--raw", str(f))
    err = res.stderr.decode()
    assert res.returncode == 0
    assert "locked on" not in err and "no protocol recognised (no good frame" in err, err


def test_auto_lock_says_how_many_frames(tmp_path):
    f = tmp_path / "exec.bin"
    f.write_bytes(stream("exec"))
    err = run_fap("monitor", "--raw", str(f)).stderr.decode()
    assert "auto: locked on exec (" in err and "good frames)" in err, err


def test_stdin_times_start_at_zero_in_the_human_view():
    res = run_fap("monitor", "--protocol", "exec", input=stream("exec"))
    first = res.stdout.decode().splitlines()[0]
    assert first.split()[0] == "0.000000", first


def test_a_long_garbage_run_is_shown_in_bounded_lines(tmp_path):
    f = tmp_path / "noise.bin"
    f.write_bytes(random.Random(3).randbytes(4139).replace(b"c", b"d"))
    out = run_fap("monitor", "--protocol", "fap", "--raw", str(f)).stdout.decode()
    lines = [ln for ln in out.splitlines() if "!! garbage" in ln]
    assert len(lines) == -(-4139 // GARBAGE_MAX)
    assert max(len(ln) for ln in lines) < 3 * GARBAGE_MAX + 60


def test_a_bad_capture_names_the_file():
    res = run_fap("monitor", "--capture", "/etc/passwd")
    assert res.returncode == 3
    assert res.stderr.decode().startswith("fap: error: /etc/passwd: line 1: bad data line")


def test_auto_keeps_trying_after_noise(tmp_path):
    """5000 bytes of noise, then exec traffic: auto still locks on exec."""
    from monitor_helpers import json_records, vectors

    data = bytes(5000) + stream("exec")
    f = tmp_path / "late.bin"
    f.write_bytes(data)
    res = run_fap("monitor", "--raw", str(f), "--json")
    assert "locked on exec" in res.stderr.decode(), res.stderr
    recs = json_records(res.stdout)
    assert "".join(r["frame"] for r in recs) == data.hex()
    good = [r for r in recs if r["ok"]]
    assert len(good) == sum(1 for v in vectors("exec") if v.ok)
    assert all(r["protocol"] == "exec" for r in good)
