"""The four G485 defects of issue 14, each through its entry point (API or ``fap`` command)."""
from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest

from fap_py.g485 import (
    WAKE_UP_PREAMBLE,
    Discarded,
    ErrorBit,
    G485Master,
    Packet,
    PacketKind,
    ParseIssue,
    Parser,
    SimDevice,
    Simulator,
    WriteRefusedError,
    codec,
)
from fap_py.port import Port, PortBusyError

SCAN_TIMEOUT = 0.01  # the issue's 10 ms


# -- 1. the preamble and the scan ---------------------------------------------------

@pytest.mark.parametrize("address", [1, 2, 9, 50, 126])
def test_request_after_preamble_parses_at_once(address: int) -> None:
    """FF FF FF FF then FF FF <addr> ...: the request comes out of the same feed (no
    "reply header" FF FF FF <addr> left waiting for bytes that never come)."""
    for request in (codec.encode_handshake_request(address), codec.encode_read_request(address, 7, 1)):
        events = Parser().feed(WAKE_UP_PREAMBLE + request)
        packets = [e for e in events if isinstance(e, Packet)]
        assert [p.raw for p in packets] == [request]
        parser = Parser()
        got = []
        for b in WAKE_UP_PREAMBLE + request:  # byte by byte, as a paced line delivers it
            got += [e for e in parser.feed(bytes((b,))) if isinstance(e, Packet)]
        assert [p.raw for p in got] == [request] and parser.buffered == 0


class RecordingDevice(SimDevice):
    """A SimDevice that keeps every parser event it is handed."""

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        super().__init__(*args, **kwargs)
        self.seen: list = []

    def handle(self, event):  # type: ignore[no-untyped-def]
        self.seen.append(event)
        return super().handle(event)


def test_simulator_answers_a_request_after_the_preamble_at_once(pty_link) -> None:
    """The request is answered when it is complete, not after the idle expiry of a
    phantom reply header (which showed up as a STALE discard and a ~20 ms stall)."""
    path, fd = pty_link
    dev = RecordingDevice(9)
    with Simulator(fd, [dev], idle_timeout=5.0) as sim, \
            G485Master(path, 115200, timeout=2.0, retries=0) as master:
        assert master.wake_up  # 115200 > 28800: the first packet carries the preamble
        t0 = time.monotonic()
        assert master.read(9, 7, check="none") == b"\x09"
        assert time.monotonic() - t0 < 5.0  # not held until the idle expiry
        assert sim.error is None
    issues = [e.issue for e in dev.seen if isinstance(e, Discarded)]
    assert ParseIssue.STALE not in issues, issues


def test_scan_finds_exactly_2_and_9_with_preamble_and_10ms(vbus) -> None:
    devices = [SimDevice(2), SimDevice(9)]
    with Simulator(vbus.paths[1], devices) as sim:
        with G485Master(vbus.paths[0], 115200, timeout=1.0) as warm:  # first contact: no 10 ms race yet
            assert warm.read(2, 7) == b"\x02" and warm.read(9, 7) == b"\x09"
        for _ in range(5):  # a fresh master each time: the preamble after open
            with G485Master(vbus.paths[0], 115200, timeout=SCAN_TIMEOUT, retries=0) as master:
                assert master.wake_up and master.wake_after_no_response
                for _ in range(2):  # and again on the same master: the preamble after each miss
                    # retries: a reply later than 10 ms on a loaded machine is retried, and a
                    # late reply taken for the next ID is refused by the ID confirmation
                    assert master.scan(range(1, 11), retries=5) == [2, 9]
        assert sim.error is None


def test_scan_command(vbus, capsys) -> None:
    from fap_py.cli import main

    with Simulator(vbus.paths[1], [SimDevice(2), SimDevice(9)]):
        with G485Master(vbus.paths[0], 115200, timeout=1.0) as warm:
            assert warm.read(2, 7) == b"\x02" and warm.read(9, 7) == b"\x09"
        assert main(["g485", "scan", "--port", vbus.paths[0], "--timeout", "0.01", "--retries", "5",
                     "--last", "12", "--json"]) == 0
    objs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    # exactly the two devices, each once, and nothing else printed
    assert [o["address"] for o in objs if o["event"] == "found"] == [2, 9]
    assert objs[-1] == {"event": "summary", "found": [2, 9], "tried": 12}
    assert len(objs) == 3


def test_master_discards_stale_input_before_each_request(pty_link) -> None:
    """A late reply waiting in the input is not taken as the answer to the next request."""
    path, fd = pty_link
    with G485Master(path, 9600, timeout=0.05, retries=0) as master:
        os.write(fd, codec.encode_read_response(7, [3]))  # device 3's reply, arriving late
        poller = select.poll()
        poller.register(master.fd, select.POLLIN)
        assert poller.poll(5000)  # it waits in the master's input queue
        with pytest.raises(Exception) as info:
            master.read(3, 7, check="none")
        assert "no reply" in str(info.value)


def test_scan_does_not_take_another_ids_reply_as_a_hit(pty_link) -> None:
    """Every probe answered with ID 5 (a late reply's content): only 5 counts."""
    path, fd = pty_link
    stop = threading.Event()

    def liar() -> None:
        parser = Parser()
        while not stop.is_set():
            try:
                data = os.read(fd, 256)
            except OSError:
                return
            for ev in parser.feed(data):
                if isinstance(ev, Packet) and ev.kind is PacketKind.READ_REQUEST:
                    os.write(fd, codec.encode_read_response(7, [5]))

    os.set_blocking(fd, True)
    t = threading.Thread(target=liar, daemon=True)
    t.start()
    try:
        with G485Master(path, 9600, timeout=0.05, retries=0) as master:
            assert master.scan([3, 4, 5, 6]) == [5]
            assert master.stats.ignored_frames >= 3
    finally:
        stop.set()


# -- 2. spy:// logs both directions --------------------------------------------------

def test_spy_url_logs_both_directions(vbus, tmp_path: Path) -> None:
    log = tmp_path / "spy.txt"
    with Simulator(vbus.paths[1], [SimDevice(4)]), \
            G485Master(f"spy://{vbus.paths[0]}?file={log}", 115200, timeout=0.5) as master:
        assert master.read(4, 7) == b"\x04"
    text = log.read_text()
    request = codec.encode_read_request(4, 7, 1)
    reply = codec.encode_read_response(7, [4])
    assert " TX " in text and " RX " in text, text
    flat = " ".join(text.split()).upper()
    assert " ".join(f"{b:02X}" for b in request[2:6]) in flat  # the request went out ...
    assert " ".join(f"{b:02X}" for b in reply[3:6]) in flat    # ... and the reply came in


# -- 3. exclusive ports ----------------------------------------------------------------

def test_second_simulator_on_a_port_is_busy(vbus) -> None:
    with Simulator(vbus.paths[1], [SimDevice(1)]):
        with pytest.raises(PortBusyError):
            Simulator(vbus.paths[1], [SimDevice(2)])


def test_master_on_a_port_held_by_another_master_is_busy(vbus) -> None:
    with G485Master(vbus.paths[0]):
        with pytest.raises(PortBusyError):
            G485Master(vbus.paths[0])
    with G485Master(vbus.paths[0]):  # closed: free again
        pass


def _wait_until_held(path: str, seconds: float = 20.0) -> None:
    """Until another process holds ``path`` (opening it is refused as busy)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            Port(path).close()
        except PortBusyError:
            return
        time.sleep(0.02)
    raise AssertionError(f"nobody took {path}")


@pytest.fixture
def exec_slave(vbus, tmp_path) -> Iterator[str]:
    proc = subprocess.Popen([sys.executable, "-m", "fap_py", "exec", "slave", "--port", vbus.paths[1],
                             "--node", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=tmp_path)
    try:
        _wait_until_held(vbus.paths[1])
        yield vbus.paths[1]
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stderr.close()  # type: ignore[union-attr]


def test_g485_read_on_a_port_held_by_exec_slave_is_busy(exec_slave, capsys) -> None:
    from fap_py.cli import main

    code = main(["g485", "read", "--port", exec_slave, "--address", "1", "--register", "7"])
    err = capsys.readouterr().err
    assert code == 3 and "busy" in err, err      # a port error, not a failure on the bus


def test_two_g485_sim_commands_on_one_port(vbus, tmp_path) -> None:
    first = subprocess.Popen([sys.executable, "-m", "fap_py", "g485", "sim", "--port", vbus.paths[1],
                              "--address", "1"], stdout=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        assert "simulating" in first.stdout.readline()  # type: ignore[union-attr]
        second = subprocess.run([sys.executable, "-m", "fap_py", "g485", "sim", "--port", vbus.paths[1],
                                 "--address", "2"], capture_output=True, text=True, timeout=30, cwd=tmp_path)
        assert second.returncode == 3 and "busy" in second.stderr, second.stderr
    finally:
        first.terminate()
        first.wait(10)
        first.stdout.close()  # type: ignore[union-attr]


# -- 4. a refused write fails ---------------------------------------------------------

def test_write_to_read_only_register_fails_the_transaction(pty_link) -> None:
    path, fd = pty_link
    dev = SimDevice(3)
    with Simulator(fd, [dev]), G485Master(path, 9600, timeout=0.2, retries=1) as master:
        master.write(3, 8, [1])  # accepted: the check byte moves to this packet's
        with pytest.raises(WriteRefusedError) as info:
            master.write(3, 1, [99])  # register 1 is read-only
        assert info.value.got != info.value.expected
        assert dev.registers[1] != 99
        assert master.error_word(3) & ErrorBit.READ_ONLY


def test_refused_write_leaves_the_check_byte_unchanged(pty_link) -> None:
    path, fd = pty_link
    dev = SimDevice(3)
    with Simulator(fd, [dev]), G485Master(path, 9600, timeout=0.2) as master:
        master.write(3, 8, [1])
        before = master.handshake(3)
        with pytest.raises(WriteRefusedError):
            master.write(3, 1, [99], retries=0)
        assert master.handshake(3) == before


def test_g485_write_command_exits_1_on_a_refused_write(vbus, capsys) -> None:
    from fap_py.cli import main

    with Simulator(vbus.paths[1], [SimDevice(1)]):
        ok = main(["g485", "write", "--port", vbus.paths[0], "--address", "1", "--register", "8", "5"])
        assert ok == 0
        code = main(["g485", "write", "--port", vbus.paths[0], "--address", "1", "--register", "2", "5"])
    err = capsys.readouterr().err
    assert code == 1 and "refused" in err, err
