"""`fap doctor PORT --listen S` on a paced virtual bus: each of the four protocols
at two rates the checker is not told names protocol and baud; nothing is sent;
a busy or vanished port ends cleanly."""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest
from doctor_helpers import doctor

from fap_py.doctor import _listen as listen_mod
from fap_py.vbus import VirtualBus

ROOT = Path(__file__).resolve().parents[3]
VECTORS = {"fap": ROOT / "tests/c/fap/vectors/fap.json",
           "exec": ROOT / "tests/vectors/exec_async.json",
           "mikroc": ROOT / "tests/vectors/mikroc_rs485.json",
           "g485": ROOT / "tests/vectors/g485.json"}
LISTEN_S = "1.5"
GAP_S = 0.015      # between frames: a quiet line, like a master's poll cycle


def frames(protocol):
    doc = json.loads(VECTORS[protocol].read_text())
    return [bytes.fromhex(v["frame"]) for v in doc["valid"]]


class Talker(threading.Thread):
    """Writes the protocol's valid frames onto the bus, round and round, until stopped."""

    def __init__(self, path, data):
        super().__init__(daemon=True)
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        self.data = data
        self.done = threading.Event()

    def run(self):
        try:
            while not self.done.is_set():
                for f in self.data:
                    os.write(self.fd, f)
                    os.tcdrain(self.fd) if hasattr(os, "tcdrain") else None
                    if self.done.wait(GAP_S + len(f) * 10.0 / self.baud):
                        return
        except OSError:
            pass

    def stop(self):
        self.done.set()
        self.join(5)
        os.close(self.fd)


@pytest.mark.timeout(10)
@pytest.mark.parametrize("baud", [9600, 38400])
@pytest.mark.parametrize("protocol", ["fap", "exec", "mikroc", "g485"])
def test_listen_names_protocol_and_baud(fap_main, protocol, baud):
    with VirtualBus(ports=2, baud=baud) as bus:
        t = Talker(bus.paths[0], frames(protocol))
        t.baud = baud
        t.start()
        try:
            code, fs, err = doctor(fap_main, bus.paths[1], "--listen", LISTEN_S)
        finally:
            t.stop()
        sent_back = bus.stats.bytes_in
    f = next(x for x in fs if x["id"] == "listen.bus")
    assert f["severity"] == "ok", (f["detail"]["errors"], f["detail"]["share"])
    assert f["detail"]["protocol"] == protocol, f
    assert f["detail"]["baud"] == baud, f
    assert f["detail"]["share"] >= 0.9 and f["detail"]["frames"] >= 2
    assert f"{protocol} at {baud} baud" in f["cause"]
    assert f["detail"]["nodes"], f
    assert "--protocol " + protocol in f["fix"]
    # nothing transmitted: the bus saw only the talker's bytes
    assert sent_back > 0


def test_listen_quiet_line(fap_main):
    with VirtualBus(ports=2, baud=9600) as bus:
        code, fs, _ = doctor(fap_main, bus.paths[1], "--listen", "0.3")
        assert bus.stats.bytes_in == 0
    f = next(x for x in fs if x["id"] == "listen.bus")
    assert f["severity"] == "warning" and "nothing heard" in f["cause"]


def test_listen_unknown_traffic(fap_main):
    with VirtualBus(ports=2, baud=19200) as bus:
        t = Talker(bus.paths[0], [b"\x00\x01\x55\x00\x02" * 4])
        t.baud = 19200
        t.start()
        try:
            code, fs, _ = doctor(fap_main, bus.paths[1], "--listen", "0.5")
        finally:
            t.stop()
    f = next(x for x in fs if x["id"] == "listen.bus")
    assert f["severity"] == "warning" and "no protocol decodes it" in f["cause"]


def test_listen_busy_port_ends_cleanly(fap_main):
    from fap_py.monitor.sources import LivePort

    with VirtualBus(ports=2) as bus:
        with LivePort(bus.paths[1], 9600):        # holds the exclusive lock
            code, fs, err = doctor(fap_main, bus.paths[1], "--listen", "0.3")
    f = next(x for x in fs if x["id"] == "listen.bus")
    assert f["severity"] == "error" and "cannot listen" in f["cause"] and code == 5
    assert "Traceback" not in err


def test_listen_vanished_port(fap_main, tmp_path):
    gone = tmp_path / "port0"
    code, fs, err = doctor(fap_main, str(gone), "--listen", "0.2")
    f = next(x for x in fs if x["id"] == "listen.bus")
    assert f["severity"] == "error" and code == 5
    assert next(x for x in fs if x["id"] == "port.exists")["severity"] == "error"


def test_listen_sweeps_rates_on_a_uart(monkeypatch):
    """A real UART gets each standard rate in turn (set through termios); a pty
    stands in for it here, so every rate hears the same frames."""
    monkeypatch.setattr(listen_mod, "STANDARD_BAUDS", (9600, 19200))
    with VirtualBus(ports=2, baud=19200) as bus:
        t = Talker(bus.paths[0], frames("mikroc"))
        t.baud = 19200
        t.start()
        try:
            f = listen_mod.listen(bus.paths[1], 0.8, pty=False)
        finally:
            t.stop()
    assert f.detail["protocol"] == "mikroc" and f.detail["baud"] in (9600, 19200)
    assert "2 rates tried" in f.evidence[0]


def test_measured_baud_needs_paced_bytes():
    assert listen_mod.measured_baud([]) is None
    now = time.monotonic_ns()
    unpaced = [(now + i, b"x") for i in range(20)]        # 1 ns apart: no standard rate
    assert listen_mod.measured_baud(unpaced) is None


def test_listen_refused_under_root(fap_main, tmp_path):
    code, _, err = fap_main("doctor", "/dev/ttyS0", "--root", str(tmp_path), "--listen", "1")
    assert code == 2 and "not with --root" in err
