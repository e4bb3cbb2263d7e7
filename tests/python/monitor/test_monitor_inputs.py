"""Every vector of every protocol through every file input of ``fap monitor``
(raw file, virtual-bus capture, stdin), and the exit codes."""
from __future__ import annotations

import pytest
from monitor_helpers import check_records, json_records, run_fap, stream, vectors

PROTOCOLS = ["fap", "exec", "mikroc", "g485"]


def write_capture(path, data: bytes, baud: int = 9600) -> None:
    """A capture in the documented format: port 0 sends the first half, port 1 the rest."""
    half = len(data) // 2
    char_us = 10_000_000 // baud
    lines = [f"# fap-vbus-capture 1 ports=2 baud={baud} echo=0 seed=0"]
    t = 1000
    for port, part in ((0, data[:half]), (1, data[half:])):
        for i in range(0, len(part), 16):
            chunk = part[i:i + 16]
            lines.append(f"{t} {port} " + " ".join(f"{b:02x}" for b in chunk))
            t += len(chunk) * char_us
        t += 5000
    lines.append(f"# end t={t} bytes_in={len(data)}")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_raw_file_every_vector(protocol, tmp_path):
    data = stream(protocol)
    f = tmp_path / "bytes.bin"
    f.write_bytes(data)
    res = run_fap("monitor", "--protocol", protocol, "--raw", str(f), "--json")
    assert res.returncode == 0, res.stderr
    recs = json_records(res.stdout)
    check_records(protocol, recs, data)
    assert all(r["t"] is None and r["port"] is None for r in recs)
    assert sum(1 for r in recs if r["ok"]) == sum(1 for v in vectors(protocol) if v.ok)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_stdin_every_vector(protocol):
    data = stream(protocol)
    res = run_fap("monitor", "--protocol", protocol, "--json", input=data)
    assert res.returncode == 0, res.stderr
    recs = json_records(res.stdout)
    check_records(protocol, recs, data)
    assert all(isinstance(r["t"], float) for r in recs)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_capture_file_every_vector_keeps_senders_and_times(protocol, tmp_path):
    data = stream(protocol)
    cap = tmp_path / "bus.cap"
    write_capture(cap, data)
    res = run_fap("monitor", "--protocol", protocol, "--capture", str(cap), "--json")
    assert res.returncode == 0, res.stderr
    recs = json_records(res.stdout)
    check_records(protocol, recs, data)
    offset, half = 0, len(data) // 2
    last_t = 0.0
    for r in recs:
        assert r["port"] == (0 if offset < half else 1)
        assert r["t"] >= last_t and r["t"] >= 0.001
        last_t = r["t"]
        offset += len(r["frame"]) // 2


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_auto_locks_on_the_right_protocol(protocol, tmp_path):
    f = tmp_path / "bytes.bin"
    f.write_bytes(stream(protocol))
    res = run_fap("monitor", "--raw", str(f), "--json")
    assert res.returncode == 0, res.stderr
    assert f"locked on {protocol}" in res.stderr.decode()
    check_records(protocol, json_records(res.stdout), stream(protocol))


def test_human_output_and_footer(tmp_path):
    f = tmp_path / "bytes.bin"
    f.write_bytes(stream("fap"))
    res = run_fap("monitor", "--protocol", "fap", "--raw", str(f))
    assert res.returncode == 0
    out = res.stdout.decode()
    assert "DATA       7 -> 0   [5] 68 65 6c 6c 6f  |hello|" in out
    assert "!! crc" in out and "!! size" in out
    assert "-- 9 frames, errors: crc 1, garbage" in out
    assert "node 7: 1 frame, " in out and "1 frames" not in out


def test_stats_only(tmp_path):
    f = tmp_path / "bytes.bin"
    f.write_bytes(stream("exec"))
    res = run_fap("monitor", "--protocol", "exec", "--raw", str(f), "--stats", "--json")
    assert res.returncode == 0
    (rec,) = json_records(res.stdout)
    st = rec["stats"]
    assert st["frames"] == 7 and st["errors"]["crc"] == 1
    assert st["bytes"] == len(stream("exec"))
    assert st["protocol"] == "exec"


def test_truncated_frame_at_end_of_file(tmp_path):
    v = vectors("exec")[1].frame
    f = tmp_path / "cut.bin"
    f.write_bytes(v + v[:5])
    res = run_fap("monitor", "--protocol", "exec", "--raw", str(f), "--json")
    assert res.returncode == 0
    recs = json_records(res.stdout)
    assert [r["error"] for r in recs] == [None, "truncated"]


def test_exit_codes(tmp_path):
    missing = run_fap("monitor", "--raw", str(tmp_path / "nope.bin"))
    assert missing.returncode == 3
    assert missing.stderr.decode().startswith("fap: error:")
    assert b"Traceback" not in missing.stderr
    assert run_fap("monitor", "--protocol", "modbus", "--raw", "x").returncode == 2
    bad_cap = tmp_path / "bad.cap"
    bad_cap.write_text("not a capture line\n")
    assert run_fap("monitor", "--capture", str(bad_cap)).returncode == 3
    assert run_fap("monitor", "--port", str(tmp_path / "no-tty"), "--baud", "9600").returncode == 3
    assert run_fap("monitor", "--raw", "x", "--follow").returncode == 2
    help_text = run_fap("monitor", "--help").stdout.decode()
    assert "example:\n  fap monitor" in help_text and "default: auto" in help_text   # the shared style
