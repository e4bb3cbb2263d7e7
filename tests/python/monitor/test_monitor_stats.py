"""Statistics from a capture with known wire times: frames and errors per
node, bytes, utilisation, reply time from the end of a request to the start
of its answer (p50/p99/max)."""
from __future__ import annotations

from monitor_helpers import json_records, run_fap, vectors

BAUD = 10_000            # one byte = 1000 us on the wire


def exec_frame(node: int, seq: int, data: bytes) -> bytes:
    from fap_py.execasync import encode

    return encode(node, data, seq)


def test_reply_times_utilisation_and_errors_per_node(tmp_path):
    lines = [f"# fap-vbus-capture 1 ports=3 baud={BAUD} echo=0 seed=0"]
    t = 1_000
    gaps_us = {3: [500, 1500, 2500], 4: [700]}
    wire = 0
    for node, gaps in gaps_us.items():
        for seq, gap in enumerate(gaps, 1):
            req = exec_frame(node, seq, b"\x01")
            ans = exec_frame(node, seq, b"\x02\x03")
            lines.append(f"{t} 0 " + req.hex(" "))
            t += len(req) * 1000 + gap            # the answer starts `gap` after the request ends
            lines.append(f"{t} {node - 2} " + ans.hex(" "))
            t += len(ans) * 1000 + 10_000
            wire += len(req) + len(ans)
    bad = next(v.frame for v in vectors("exec") if not v.ok)
    lines.append(f"{t} 0 " + bad.hex(" "))
    wire += len(bad)
    span_us = t + len(bad) * 1000 - 1_000
    cap = tmp_path / "bus.cap"
    cap.write_text("\n".join(lines) + "\n")

    res = run_fap("monitor", "--protocol", "exec", "--capture", str(cap), "--stats", "--json")
    assert res.returncode == 0, res.stderr
    (rec,) = json_records(res.stdout)
    st = rec["stats"]
    assert st["frames"] == 8 and st["errors"] == {"crc": 1} and st["bytes"] == wire
    n3, n4 = st["nodes"]["3"], st["nodes"]["4"]
    assert (n3["frames"], n3["replies"]) == (6, 3)
    assert (n3["reply_p50_ms"], n3["reply_p99_ms"], n3["reply_max_ms"]) == (1.5, 2.5, 2.5)
    assert (n4["replies"], n4["reply_max_ms"]) == (1, 0.7)
    assert st["nodes"]["?"]["errors"] == {"crc": 1}
    assert abs(st["utilisation"] - wire * 1000 / span_us) < 1e-3

    human = run_fap("monitor", "--protocol", "exec", "--capture", str(cap), "--stats")
    text = human.stdout.decode()
    assert text.startswith("-- 8 frames, errors: crc 1;")
    assert "node 3: 6 frames, no errors; reply ms p50 1.5 p99 2.5 max 2.5 (3)" in text


def test_unknown_protocol_is_a_fap_error():
    import pytest

    from fap_py.errors import InvalidValueError
    from fap_py.monitor import Monitor

    with pytest.raises(InvalidValueError):
        Monitor("modbus")


def test_reply_times_are_kept_bounded_on_a_long_run(monkeypatch):
    """A long live run: reply samples stop growing; counts and max stay exact."""
    from fap_py.monitor import Event, Record
    from fap_py.monitor import stats as stats_mod

    monkeypatch.setattr(stats_mod, "REPLY_SAMPLES", 100)
    st = stats_mod.Stats(115200)
    t = 1.0
    for i in range(1000):
        for master in (True, False):
            ev = Event("mikroc", 0, b"\x96\x05\x80\x00\xa9", None,
                       {"address": 5, "from_master": master, "data": b""})
            st.add(Record(ev, t, t + 0.0001, None))
            t += 0.001 + (0.01 if i == 500 and master else 0.0)
    node = st.nodes["5"]
    assert len(node.replies) == 100 and node.n_replies == 1000
    summary = st.summary()["nodes"]["5"]
    assert summary["replies"] == 1000
    assert summary["reply_max_ms"] == round(node.reply_max * 1e3, 3) and node.reply_max > 0.01
