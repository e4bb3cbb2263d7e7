"""``fap monitor --pcap`` read back by tshark with the shipped Lua dissector
agrees with ``--json`` field by field; display filters work; tshark lists
the extcap interface. Needs tshark (skips without it only when CI is unset)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from monitor_helpers import json_records, need_tool, run_fap, stream
from test_monitor_inputs import write_capture

from fap_py.monitor.decoders import dissector, fields, monitor_protocols

PROTOCOLS = list(monitor_protocols())
#: JSON protocol name -> the dissector's filter prefix (from the plug-ins)
PREFIX = {p: dissector(p) for p in PROTOCOLS}
FIELDS = fields()
TSHARK_TIMEOUT = 120.0


def tshark(*args: str, env=None) -> str:
    exe = need_tool("tshark")
    res = subprocess.run([exe, *args], capture_output=True, timeout=TSHARK_TIMEOUT, env=env)
    assert res.returncode == 0, res.stderr.decode()
    return res.stdout.decode()


@pytest.fixture(scope="module")
def lua(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dissectors")
    res = run_fap("monitor", "--dissectors", str(out))
    assert res.returncode == 0, res.stderr
    (path,) = list(out.glob("*.lua"))
    return path


def as_json_value(key: str, text: str):
    """A tshark -T fields value in --json's spelling."""
    if text == "":
        return None
    if key in ("data", "frame"):
        return text.replace(":", "").lower()
    if key in ("msg_name", "packet", "protocol", "error"):
        return text
    if key in ("ok", "from_master"):
        return text in ("1", "True", "TRUE")
    return int(text, 0)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_pcap_agrees_with_json(protocol, lua, tmp_path):
    data = stream(protocol)
    cap = tmp_path / "bus.cap"
    write_capture(cap, data)
    pcap = tmp_path / "out.pcap"
    res = run_fap("monitor", "--protocol", protocol, "--capture", str(cap), "--json",
                  "--pcap", str(pcap))
    assert res.returncode == 0, res.stderr
    recs = json_records(res.stdout)
    common = ("protocol", "ok", "error", "frame", "port")
    names = [f"fapmon.{k}" for k in common] + \
        [f"{PREFIX[protocol]}.{k}" for k in FIELDS[protocol]]
    args = ["-X", f"lua_script:{lua}", "-r", str(pcap), "-T", "fields",
            "-E", "separator=/t", "-e", "_ws.col.Source", "-e", "_ws.col.Destination",
            "-e", "frame.time_epoch"]
    for n in names:
        args += ["-e", n]
    lines = tshark(*args).splitlines()
    assert len(lines) == len(recs)
    keys = common + FIELDS[protocol]
    for line, rec in zip(lines, recs):
        src, dst, *cols = line.split("\t")
        if rec["ok"]:         # who sent a good frame to whom (issue 25: the columns were empty)
            assert src and dst, f"empty Source/Destination: {line!r}"
        assert abs(float(cols[0]) - rec["t"]) < 2e-6, (cols[0], rec["t"])
        got = {k: as_json_value(k, c) for k, c in zip(keys, cols[1:])}
        if got["error"] is None and not rec["ok"]:
            pytest.fail(f"error missing in {line!r}")
        want = {k: rec[k] for k in keys}
        if rec["ok"] and want.get("data") == "":
            want["data"] = None          # an empty data field is absent in Wireshark
        assert got == want, (line, rec)


def test_display_filters(lua, tmp_path):
    f = tmp_path / "fap.bin"
    f.write_bytes(stream("fap"))
    pcap = tmp_path / "fap.pcap"
    res = run_fap("monitor", "--protocol", "fap", "--raw", str(f), "--json", "--pcap", str(pcap))
    recs = json_records(res.stdout)
    want = sum(1 for r in recs if r["ok"] and r["src"] == 1)
    assert want >= 1
    out = tshark("-X", f"lua_script:{lua}", "-r", str(pcap), "-Y", "fap.src == 1")
    assert len(out.splitlines()) == want
    bad = tshark("-X", f"lua_script:{lua}", "-r", str(pcap), "-Y", 'fapmon.error == "crc"')
    assert len(bad.splitlines()) == sum(1 for r in recs if r["error"] == "crc")


def test_tshark_lists_the_extcap_interface(tmp_path):
    need_tool("tshark")
    conf = tmp_path / "xdg"
    # Wireshark 4.0 looks in <personal configuration>/extcap; it ignores
    # WIRESHARK_EXTCAP_DIR when run as root, XDG_CONFIG_HOME moves the personal dir
    res = run_fap("monitor", "--extcap-dir", str(conf / "wireshark" / "extcap"))
    assert res.returncode == 0, res.stderr
    env = dict(os.environ, XDG_CONFIG_HOME=str(conf))
    out = tshark("-D", env=env)
    assert "fap_monitor (fap monitor: FAP, exec async, mikroC, G485 on a serial port)" in out
    launcher = conf / "wireshark" / "extcap" / "fap-monitor-extcap"
    dlts = subprocess.run([str(launcher), "--extcap-interface", "fap_monitor", "--extcap-dlts"],
                          capture_output=True, timeout=60).stdout.decode()
    assert "{number=147}" in dlts
    config = subprocess.run([str(launcher), "--extcap-interface", "fap_monitor", "--extcap-config"],
                            capture_output=True, timeout=60).stdout.decode()
    assert "{call=--port}" in config and "{value=g485}" in config
