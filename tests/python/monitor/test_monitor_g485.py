"""A real G485 master and simulator on the virtual bus (issue 25's repro):
the wake-up preamble is one good record, not errors; records never overlap
(their bytes add up to what was on the bus); replies name the device they
answer; the live view's times never go backwards; tshark with the shipped
dissector agrees and fills the Source/Destination columns."""
from __future__ import annotations

import pytest
from monitor_helpers import fap_cmd, json_records, run_fap
from test_monitor_live import WAIT_S, start_monitor
from test_monitor_wireshark import as_json_value, lua, tshark  # noqa: F401 - lua is a fixture

from fap_py.g485 import G485Master, SimDevice, Simulator
from fap_py.monitor.decoders import FIELDS
from fap_py.monitor.protocols.g485 import PREAMBLE as G485_PREAMBLE
from fap_py.vbus import read_capture

BAUD = 115200            # above 28,800: the master sends the wake-up preamble


def talk(bus_paths) -> None:
    """The issue's `fap g485 read --address 1 --register 1 --registers 7` and a handshake."""
    sim = Simulator(bus_paths[1], [SimDevice(1)], baudrate=BAUD).start()
    try:
        with G485Master(bus_paths[0], BAUD, timeout=1.0) as master:
            assert len(master.read(1, 1, 7)) == 7
            master.handshake(1)
    finally:
        sim.stop()


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from fap_py.vbus import VirtualBus

    path = tmp_path_factory.mktemp("g485") / "bus.cap"
    with VirtualBus(ports=3, capture=str(path)) as bus:
        talk(bus.paths)
    return path


def on_the_bus(path) -> bytes:
    return b"".join(r.data for r in read_capture(path).records)


def test_preamble_is_one_good_record_and_records_tile_the_bus(capture):
    res = run_fap("monitor", "--capture", str(capture), "--protocol", "g485", "--json")
    assert res.returncode == 0, res.stderr
    recs = json_records(res.stdout)
    assert "".join(r["frame"] for r in recs) == on_the_bus(capture).hex()
    assert [r for r in recs if not r["ok"]] == []
    pre = [r for r in recs if r["packet"] == G485_PREAMBLE]
    assert pre and all(r["frame"] == "ffffffff" for r in pre)
    for r in recs:
        if r["packet"].endswith("Response"):
            assert r["address"] == 127 and r["device"] == 1
        elif r["packet"] != G485_PREAMBLE:
            assert r["device"] == r["address"] == 1
    stats = run_fap("monitor", "--capture", str(capture), "--protocol", "g485", "--stats")
    footer = stats.stdout.decode()
    frames = sum(1 for r in recs if r["packet"] != G485_PREAMBLE)
    assert f"-- {frames} frames, errors: none" in footer, footer
    assert f"node 1: {frames} frames, no errors" in footer, footer


def test_human_view_names_the_answering_device(capture):
    out = run_fap("monitor", "--capture", str(capture), "--protocol", "g485").stdout.decode()
    assert "Wake-up-Preamble" in out and "!!" not in out
    assert "User-Register-Read-Response 1 -> master" in out and "addr 127" not in out


def test_tshark_agrees_and_fills_source_and_destination(capture, lua, tmp_path):  # noqa: F811
    pcap = tmp_path / "g485.pcap"
    res = run_fap("monitor", "--capture", str(capture), "--protocol", "g485", "--json",
                  "--pcap", str(pcap))
    recs = json_records(res.stdout)
    keys = ("ok", "error") + FIELDS["g485"]
    args = ["-X", f"lua_script:{lua}", "-r", str(pcap), "-T", "fields", "-E", "separator=/t",
            "-e", "_ws.col.Source", "-e", "_ws.col.Destination", "-e", "fapmon.ok",
            "-e", "fapmon.error"] + [a for k in FIELDS["g485"] for a in ("-e", f"g485.{k}")]
    lines = tshark(*args).splitlines()
    assert len(lines) == len(recs)
    for line, rec in zip(lines, recs):
        cols = line.split("\t")
        assert cols[0] and cols[1], f"empty Source/Destination: {line!r}"
        got = {k: as_json_value(k, c) for k, c in zip(keys, cols[2:])}
        want = {k: rec[k] for k in keys}
        if want["data"] == "":
            want["data"] = None
        assert got == want, (line, rec)
        if rec["packet"].endswith("Response"):
            assert (cols[0], cols[1]) == ("1", "master")
    assert "[length]" not in tshark("-X", f"lua_script:{lua}", "-r", str(pcap))


def test_live_view_times_never_go_backwards():
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=3) as bus:
        proc = start_monitor(fap_cmd() + ["monitor", "--protocol", "g485", "--port",
                                          bus.paths[2], "--baud", str(BAUD), "--json",
                                          "--idle", "1.0"])
        talk(bus.paths)
        out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    recs = json_records(out)
    assert [r for r in recs if not r["ok"]] == [] and len(recs) >= 5
    times = [r["t"] for r in recs]
    assert times == sorted(times)
