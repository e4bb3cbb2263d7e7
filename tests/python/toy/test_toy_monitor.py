"""The monitor picks the toy protocol up with no edit to fap_py: its plug-in
(toyproto/monitor/protocols/toy.py) is found by name through the protocol table, in
process (Monitor, JSON, human line, pcap, statistics, ``auto``) and in ``fap monitor``
run as a program with the toy's row in FAP_EXTRA_PROTOCOLS."""
from __future__ import annotations

import io
import json
import subprocess
import sys

from toyproto import binding
from toyproto.monitor.protocols import toy as toy_plugin

from fap_py import _protocols
from fap_py.monitor import PROTOCOLS, Monitor
from fap_py.monitor.decoders import make_decoder
from fap_py.monitor.output import human_line, to_json
from fap_py.monitor.pcap import PcapWriter
from fap_py.monitor.stats import Stats

RUN_TIMEOUT = 60.0
GARBAGE = b"\x00\x01\x55"      # starts no frame of any protocol
REQ3 = binding.encode(3, b"\x01\x02")
ANS3 = binding.encode(3, b"\x02\x01", reply=True)
REQ4 = binding.encode(4, b"\x07")
ANS4 = binding.encode(4, b"\x07", reply=True)
BAD = REQ4[:-1] + bytes([REQ4[-1] ^ 1])          # check byte wrong
PARTIAL = REQ3[:3]
STREAM = GARBAGE + REQ3 + ANS3 + GARBAGE + BAD + REQ4 + ANS4 + PARTIAL


def decode_all(protocol: str, data: bytes = STREAM):
    mon = Monitor(protocol, 9600)
    recs = mon.feed(data, t=1.0, char_s=1e-3, port=0) + mon.finish()
    return mon, recs


def test_the_plugin_is_found_by_name():
    assert _protocols.get("toy").plugin("monitor") is toy_plugin
    assert "toy" in PROTOCOLS
    assert make_decoder("toy").name == "toy"


def test_monitor_decodes_the_toy():
    _mon, recs = decode_all("toy")
    assert b"".join(r.raw for r in recs) == STREAM, "records tile the stream"
    good = [r for r in recs if r.ok]
    assert [r.raw for r in good] == [REQ3, ANS3, REQ4, ANS4]
    assert good[1].fields == {"node": 3, "reply": True, "data": b"\x02\x01"}
    assert [r.error for r in recs if not r.ok] == ["garbage", "garbage", "check", "truncated"]
    assert next(r for r in recs if r.error == "check").raw == BAD

    j = to_json(good[0])
    assert (j["protocol"], j["node"], j["reply"], j["data"]) == ("toy", 3, False, "0102")
    assert "node 3 request" in human_line(good[0])

    out = io.BytesIO()
    with PcapWriter(out) as pcap:
        pcap.write(good[0])
    assert out.getvalue()[24 + 16 + 1] == _protocols.get("toy").pcap_id

    st = Stats(9600)
    for r in recs:
        st.add(r)
    s = st.summary()
    assert s["frames"] == 4 and s["errors"] == {"garbage": 2, "check": 1, "truncated": 1}
    assert s["nodes"]["3"]["replies"] == 1 and s["nodes"]["4"]["replies"] == 1


def test_auto_finds_the_toy():
    mon, recs = decode_all("auto")
    assert mon.locked == "toy"
    assert [r.raw for r in recs if r.ok] == [REQ3, ANS3, REQ4, ANS4]


def run_fap(env, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fap_py", *args], env=env, capture_output=True,
                          timeout=RUN_TIMEOUT, stdin=subprocess.DEVNULL)


def test_fap_monitor_as_a_program_decodes_the_toy(toy_env, tmp_path):
    raw = tmp_path / "toy.bin"
    raw.write_bytes(STREAM)
    for protocol in ("toy", "auto"):
        res = run_fap(toy_env, "monitor", "--protocol", protocol, "--raw", str(raw), "--json")
        assert res.returncode == 0, res.stderr.decode()
        recs = [json.loads(line) for line in res.stdout.decode().splitlines() if line.strip()]
        assert "".join(r["frame"] for r in recs) == STREAM.hex()
        good = [r for r in recs if r["ok"]]
        assert [r["frame"] for r in good] == [f.hex() for f in (REQ3, ANS3, REQ4, ANS4)]
        assert all(r["protocol"] == "toy" for r in recs)
        assert [(r["node"], r["reply"]) for r in good] == [(3, False), (3, True), (4, False), (4, True)]
