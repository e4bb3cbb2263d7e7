"""``fap monitor --port`` on the virtual bus while nodes talk: every vector
of every protocol from a node, a real exec async master and slave (reply
times), the exclusive lock, and the extcap capture into a pcap."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import time
from typing import List

import pytest
from monitor_helpers import check_records, fap_cmd, json_records, need_tool, stream, vectors

from fap_py.execasync import RS485, Master, RS485Mode, Slave
from fap_py.vbus import VirtualBus

PROTOCOLS = ["fap", "exec", "mikroc", "g485"]
WAIT_S = 20.0            # deadline for the monitor to start listening or to finish
IDLE_S = "1.0"           # the monitor stops after this much silence (its own rule)
LINE = RS485(mode=RS485Mode.NONE)   # ptys have no RS-485 ioctls


def start_monitor(args: List[str]) -> subprocess.Popen:
    """Start ``fap monitor`` and wait until it says it listens (its port is open)."""
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + WAIT_S
    seen = b""
    while b"listening on" not in seen:
        left = deadline - time.monotonic()
        ready, _, _ = select.select([proc.stderr], [], [], max(0.0, left))
        if not ready:
            proc.kill()
            pytest.fail(f"monitor did not start: {seen!r}")
        chunk = os.read(proc.stderr.fileno(), 4096)
        if not chunk:
            pytest.fail(f"monitor exited: {seen!r} rc={proc.wait()}")
        seen += chunk
    return proc


def node_write(path: str, data: bytes) -> None:
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        # close only once the relay took the bytes: wait until the pty drained
        import termios
        termios.tcdrain(fd)
    finally:
        os.close(fd)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_live_port_every_vector(protocol):
    data = stream(protocol)
    with VirtualBus(ports=3) as bus:
        proc = start_monitor(fap_cmd() + ["monitor", "--protocol", protocol, "--port",
                                          bus.paths[2], "--baud", "115200", "--json",
                                          "--idle", IDLE_S])
        node_write(bus.paths[0], data)
        out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    recs = json_records(out)
    check_records(protocol, recs, data)
    assert all(isinstance(r["t"], float) for r in recs)


def read_json_line(proc: subprocess.Popen) -> dict:
    """The monitor's next JSON record (it flushes each one on a live port)."""
    ready, _, _ = select.select([proc.stdout], [], [], WAIT_S)
    assert ready, "no record from the monitor"
    return json.loads(proc.stdout.readline())


@pytest.mark.parametrize("protocol", ["fap", "g485"])
def test_live_inter_byte_gap_abandons_a_partial_frame(protocol):
    """A frame whose rest never comes is reported ("gap") once the line is quiet,
    and the next frame decodes: the receivers' gap rule, applied while following."""
    good = next(v.frame for v in vectors(protocol) if v.ok)
    with VirtualBus(ports=3) as bus:
        proc = start_monitor(fap_cmd() + ["monitor", "--protocol", protocol, "--port",
                                          bus.paths[2], "--baud", "115200", "--json", "--follow"])
        try:
            node_write(bus.paths[0], good[:5])
            first = read_json_line(proc)        # written only after the gap expired
            node_write(bus.paths[0], good)
            second = read_json_line(proc)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0
    assert (first["ok"], first["error"], first["frame"]) == (False, "gap", good[:5].hex())
    assert (second["ok"], second["frame"]) == (True, good.hex())


def test_live_exec_master_and_slave_reply_times():
    with VirtualBus(ports=3) as bus:
        proc = start_monitor(fap_cmd() + ["monitor", "--protocol", "exec", "--port",
                                          bus.paths[2], "--baud", "115200", "--idle", IDLE_S])
        with Slave(bus.paths[1], node=7, handler=lambda req: req.data[::-1], rs485=LINE) as slave, \
                Master(bus.paths[0], timeout=2.0, retries=0, rs485=LINE) as master:
            slave.start()
            for i in range(5):
                assert master.transact(7, bytes([i, 0x10, 0x41])) == bytes([0x41, 0x10, i])
        out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    text = out.decode()
    frames = [line for line in text.splitlines() if "node   7 seq" in line]
    assert len(frames) == 10, text
    assert "node 7: 10 frames, no errors; reply ms p50" in text
    assert "(5)" in text        # five request/answer pairs timed


def test_live_port_lock_is_honoured():
    from fap_py.monitor.sources import LivePort

    with VirtualBus(ports=2) as bus:
        with LivePort(bus.paths[1], 9600):
            res = subprocess.run(fap_cmd() + ["monitor", "--port", bus.paths[1], "--baud", "9600",
                                              "--idle", "0.1"],
                                 capture_output=True, timeout=WAIT_S)
    assert res.returncode == 3
    assert res.stderr.decode().startswith("fap: error:")


def test_live_port_any_termios_rate_and_bad_rate():
    with VirtualBus(ports=2) as bus:
        ok = subprocess.run(fap_cmd() + ["monitor", "--port", bus.paths[1], "--baud", "1500000",
                                         "--idle", "0.1", "--stats"],
                            capture_output=True, timeout=WAIT_S)
        assert ok.returncode == 0, ok.stderr
        bad = subprocess.run(fap_cmd() + ["monitor", "--port", bus.paths[1], "--baud", "12345",
                                          "--idle", "0.1"], capture_output=True, timeout=WAIT_S)
    assert bad.returncode == 2, bad.stderr


def test_extcap_capture_to_pcap(tmp_path):
    """Wireshark's call: --capture --fifo FIFO; stopped with SIGTERM as Wireshark does."""
    res = subprocess.run(fap_cmd() + ["monitor", "--extcap-dir", str(tmp_path)],
                         capture_output=True, timeout=WAIT_S)
    assert res.returncode == 0
    launcher = tmp_path / "fap-monitor-extcap"
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    data = stream("mikroc")
    with VirtualBus(ports=2) as bus:
        proc = subprocess.Popen([str(launcher), "--capture", "--extcap-interface", "fap_monitor",
                                 "--fifo", str(fifo), "--port", bus.paths[1], "--baud", "115200",
                                 "--protocol", "mikroc"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        rfd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)   # the reader end, as Wireshark
        try:
            pcap = _read_fifo(rfd, 24)           # the header: written once the port is open
            node_write(bus.paths[0], data)
            while _pcap_frames_hex(pcap) != data.hex():      # garbage too, once the line is quiet
                more = _read_fifo(rfd, 1)
                assert more, f"capture ended early: {_pcap_frames_hex(pcap)}"
                pcap += more
        finally:
            proc.send_signal(signal.SIGTERM)
            _out, err = proc.communicate(timeout=WAIT_S)
            pcap += _read_fifo(rfd, 0)
            os.close(rfd)
    assert proc.returncode == 0
    assert err == b"", err                       # Wireshark shows any stderr as an error
    assert _pcap_frames_hex(pcap) == data.hex()
    out_file = tmp_path / "live.pcap"
    out_file.write_bytes(pcap)
    tshark = need_tool("tshark")
    lua_dir = tmp_path / "lua"
    subprocess.run(fap_cmd() + ["monitor", "--dissectors", str(lua_dir)], check=True,
                   capture_output=True, timeout=WAIT_S)
    out = subprocess.run([tshark, "-X", f"lua_script:{lua_dir / 'fap_monitor.lua'}", "-r",
                          str(out_file), "-Y", "mikroc.address == 160"],
                         capture_output=True, timeout=120).stdout.decode()
    assert len(out.splitlines()) == 2


def _read_fifo(fd: int, at_least: int) -> bytes:
    """Read what the fifo holds, waiting (deadline) until at least ``at_least`` bytes came."""
    out = b""
    deadline = time.monotonic() + WAIT_S
    while True:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            chunk = None
        if chunk:
            out += chunk
            if len(out) >= at_least:
                return out
            continue
        if len(out) >= at_least:
            return out
        left = deadline - time.monotonic()
        if left <= 0:
            return out
        select.select([fd], [], [], left)


def _pcap_frames_hex(raw: bytes) -> str:
    """The frames of a fap monitor pcap, concatenated (header skipped)."""
    import struct

    out, pos = [], 24
    while pos + 16 <= len(raw):
        _s, _u, incl, _orig = struct.unpack_from("<IIII", raw, pos)
        pkt = raw[pos + 16:pos + 16 + incl]
        if len(pkt) < incl:
            break
        out.append(pkt[5 + pkt[4]:].hex())
        pos += 16 + incl
    return "".join(out)

