"""Issue 33 item 2: a master's retry is a second request, never the node's
reply. An exec async master retrying a node that does not exist, recorded
by the bus (a capture, whose lines name the sender port) and read live from
a port (no sender: the retry repeats the request byte for byte), shows the
node's frames and no reply time; a real slave's replies are still timed."""
from __future__ import annotations

from pathlib import Path

import pytest
from monitor_helpers import fap_cmd, json_records, run_fap
from test_monitor_live import IDLE_S, LINE, WAIT_S, start_monitor

from fap_py.execasync import Master, NoReplyError, Slave
from fap_py.vbus import VirtualBus

ABSENT = 9
RETRIES = 3


def _retry_absent(path: str) -> None:
    with Master(path, timeout=0.03, retries=RETRIES, rs485=LINE) as master:
        with pytest.raises(NoReplyError):
            master.transact(ABSENT, b"\x01\x02")


def test_capture_of_retries_to_an_absent_node_has_no_reply(tmp_path: Path) -> None:
    cap = tmp_path / "retries.cap"
    with VirtualBus(ports=2, baud=115200, capture=cap) as bus:
        _retry_absent(bus.paths[0])
    res = run_fap("monitor", "--protocol", "exec", "--capture", str(cap), "--stats", "--json")
    assert res.returncode == 0, res.stderr
    (rec,) = json_records(res.stdout)
    node = rec["stats"]["nodes"][str(ABSENT)]
    assert node["frames"] == 1 + RETRIES          # the request and its retries, all seen
    assert (node["replies"], node["reply_p50_ms"]) == (0, None)
    human = run_fap("monitor", "--protocol", "exec", "--capture", str(cap), "--stats")
    text = human.stdout.decode()
    assert f"node {ABSENT}: {1 + RETRIES} frames, no errors" in text
    assert "reply ms" not in text, text


def test_capture_echo_slave_replies_are_timed(tmp_path: Path) -> None:
    """An echoing slave's reply is byte-identical to the request: the capture's
    sender port tells it from a retry."""
    cap = tmp_path / "echo.cap"
    with VirtualBus(ports=2, baud=115200, capture=cap) as bus:
        with Slave(bus.paths[1], node=7, handler=lambda req: req.data, rs485=LINE) as slave, \
                Master(bus.paths[0], timeout=2.0, retries=0, rs485=LINE) as master:
            slave.start()
            for i in range(3):
                assert master.transact(7, bytes([i])) == bytes([i])
    res = run_fap("monitor", "--protocol", "exec", "--capture", str(cap), "--stats", "--json")
    (rec,) = json_records(res.stdout)
    node = rec["stats"]["nodes"]["7"]
    assert (node["frames"], node["replies"]) == (6, 3)


def test_live_retries_to_an_absent_node_have_no_reply() -> None:
    with VirtualBus(ports=2) as bus:
        proc = start_monitor(fap_cmd() + ["monitor", "--protocol", "exec", "--port",
                                          bus.paths[1], "--baud", "115200", "--idle", IDLE_S,
                                          "--stats"])
        _retry_absent(bus.paths[0])
        out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    text = out.decode()
    assert f"node {ABSENT}: {1 + RETRIES} frames, no errors" in text, text
    assert "reply ms" not in text, text
