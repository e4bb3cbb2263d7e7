"""fap_py.vbus.VirtualBus: the C bus through the Python wrapper, on real ptys."""
from __future__ import annotations

import errno
import os
import select
import time
from pathlib import Path

import pytest
import serial
from vbus_helpers import WAIT_S, open_port, pending, read_exact, write_all

from fap_py.errors import ClosedError, FapError, InvalidValueError, PortError
from fap_py.vbus import CaptureFormatError, VirtualBus, VirtualBusStats, parse_capture, read_capture


def test_bytes_reach_every_other_port_not_the_sender(open_nodes) -> None:
    with VirtualBus(ports=4) as bus:
        assert len(bus.paths) == 4
        assert all(os.readlink(p).startswith("/dev/pts/") for p in bus.paths)
        fds = open_nodes(bus)
        write_all(fds[0], b"\x7e\x01\x02\x03")
        for fd in fds[1:]:
            assert read_exact(fd, 4) == b"\x7e\x01\x02\x03"
        # a later marker from port 1 is the first thing port 0 gets: no echo
        write_all(fds[1], b"M")
        assert read_exact(fds[0], 1) == b"M"
        st = bus.stats
        assert isinstance(st, VirtualBusStats)
        assert st.bytes_in == 5
        assert st.collisions == 0
    assert bus.closed
    assert not any(os.path.lexists(p) for p in bus.paths)


def test_echo_returns_bytes_to_the_sender(open_nodes) -> None:
    with VirtualBus(ports=2, echo=True) as bus:
        a, b = open_nodes(bus)
        write_all(a, b"ping")
        assert read_exact(a, 4) == b"ping"
        assert read_exact(b, 4) == b"ping"


def test_pyserial_node_on_a_bus_port(tmp_path: Path) -> None:
    with VirtualBus(ports=3, link_dir=tmp_path / "links") as bus:
        assert bus.paths[0] == str(tmp_path / "links" / "port0")
        with serial.Serial(bus.paths[0], 115200, timeout=WAIT_S) as s0, \
                serial.Serial(bus.paths[2], 115200, timeout=WAIT_S) as s2:
            s0.write(b"hello")
            assert s2.read(5) == b"hello"
    assert not (tmp_path / "links").exists()


def test_paced_frame_takes_its_wire_time(open_nodes) -> None:
    with VirtualBus(ports=2, baud=9600) as bus:
        a, b = open_nodes(bus)
        frame = bytes(range(100))
        t0 = time.monotonic()
        write_all(a, frame)
        assert read_exact(b, 100, timeout=5) == frame
        elapsed = time.monotonic() - t0
        assert 0.095 <= elapsed < 5.0   # 104.2 ms ideal; loose on purpose
        st = bus.stats
        assert st.paced_bytes == 100
        assert 0.0 <= st.pace_late_mean_us <= st.pace_late_max_ns / 1000.0


def test_forced_collision_is_detected(tmp_path: Path, open_nodes) -> None:
    with VirtualBus(ports=3, baud=9600, capture=tmp_path / "c.cap") as bus:
        a, b, c = open_nodes(bus)
        write_all(a, b"\x11" * 64)   # ~67 ms on the wire...
        write_all(b, b"\x22" * 64)   # ...so this one overlaps it
        got = read_exact(c, 128, timeout=5)
        assert len(got) == 128
        assert got.count(0xEE) > 0 and got.count(0xDD) > 0   # bit-inverted
        assert set(got) <= {0x11, 0x22, 0xEE, 0xDD}
        assert bus.stats.collisions == 1
    cap = read_capture(tmp_path / "c.cap")
    [event] = cap.events_of("collision")
    assert event.fields == {"ports": "0,1"}
    # what the capture shows is what the receivers got
    sent_a, sent_b = cap.data_from(0), cap.data_from(1)
    assert len(sent_a) == len(sent_b) == 64
    assert 0xEE in sent_a and set(sent_a) <= {0x11, 0xEE}
    assert 0xDD in sent_b and set(sent_b) <= {0x22, 0xDD}
    # a corrupted byte started at most one char time (1042 us) before the overlap
    assert all(r.t_us >= event.t_us - 1042 for r in cap.records if r.data[0] in (0xEE, 0xDD))


def test_drop_next_and_corrupt_next_are_exact(open_nodes) -> None:
    with VirtualBus(ports=2, seed=3) as bus:
        a, b = open_nodes(bus)
        msg = bytes(range(10))
        bus.drop_next(0, 4)
        write_all(a, msg)
        assert read_exact(b, 6) == msg[4:]
        bus.corrupt_next(0, 3)
        write_all(a, msg)
        got = read_exact(b, 10)
        assert [bin(x ^ y).count("1") for x, y in zip(got, msg)] == [1, 1, 1] + [0] * 7
        st = bus.stats
        assert (st.dropped, st.bit_errors) == (4, 3)


def _ber_run(seed: int, open_nodes) -> tuple:
    with VirtualBus(ports=2, seed=seed) as bus:
        a, b = open_nodes(bus)
        bus.set_fault(None, bit_error_rate=0.25)
        write_all(a, b"\x00" * 300)
        got = read_exact(b, 300)
        return got, bus.stats.bit_errors


def test_seeded_bit_errors_reproduce(open_nodes) -> None:
    first, n1 = _ber_run(1234, open_nodes)
    again, n2 = _ber_run(1234, open_nodes)
    other, _ = _ber_run(99, open_nodes)
    assert len(first) == 300
    assert first == again and n1 == n2
    assert other != first
    assert sum(bin(x).count("1") for x in first) == n1
    assert 30 < n1 < 130   # ~75 expected


def test_silence_and_disconnect(open_nodes) -> None:
    with VirtualBus(ports=3) as bus:
        a, b, c = open_nodes(bus)
        bus.silence(1, 60)
        write_all(a, b"x")
        assert read_exact(c, 1) == b"x"
        assert not pending(b)   # delivered to c in the same step, not to b
        bus.silence(1, 0)       # lifted
        write_all(a, b"y")
        assert read_exact(b, 1) == b"y"

        bus.disconnect(1, 0.1)
        ready, _, _ = select.select([b], [], [], WAIT_S)
        assert ready
        with pytest.raises(OSError) as info:
            os.write(b, b"z")
        assert info.value.errno == errno.EIO
        with pytest.raises(FileNotFoundError):
            os.open(bus.paths[1], os.O_RDWR | os.O_NOCTTY)
        deadline = time.monotonic() + WAIT_S
        fd = None
        while fd is None and time.monotonic() < deadline:
            try:
                fd = open_port(bus.paths[1])
            except FileNotFoundError:
                select.select([], [], [], 0.005)   # a node's reopen pacing
        assert fd is not None
        try:
            write_all(a, b"back")
            assert read_exact(fd, 4) == b"back"
        finally:
            os.close(fd)
        assert bus.stats.disconnects == 1


def test_capture_file_records_bytes_and_ports(tmp_path: Path, open_nodes) -> None:
    cap_path = tmp_path / "bus.cap"
    with VirtualBus(ports=3, baud=115200, capture=cap_path, seed=5) as bus:
        a, b, c = open_nodes(bus)
        write_all(a, b"abc")
        assert read_exact(c, 3) == b"abc"
        assert read_exact(b, 3) == b"abc"
        write_all(b, bytes(range(100)))
        assert read_exact(c, 100) == bytes(range(100))
        bus.drop_next(2, 1)
        write_all(c, b"QR")      # Q dropped (it still held the wire for a char time)
        assert read_exact(b, 1) == b"R"
        write_all(a, b"!")
        assert read_exact(b, 1) == b"!"
    cap = read_capture(cap_path)
    assert cap.header == {"ports": "3", "baud": "115200", "echo": "0", "seed": "5"}
    assert cap.data_from(0) == b"abc!"
    assert cap.data_from(1) == bytes(range(100))
    assert cap.data_from(2) == b"R"
    # long runs are split; times follow the wire (86.8 us per byte at 115200)
    recs = [r for r in cap.records if r.port == 1]
    assert len(recs) >= 2
    assert recs[1].t_us - recs[0].t_us == pytest.approx(len(recs[0].data) * 86.8, abs=2)
    faults = cap.events_of("fault")
    assert [(e.fields["port"], e.fields["reason"], e.fields["n"]) for e in faults] == \
        [("2", "drop_next", "1")]
    assert cap.events_of("end")[0].fields["bytes_in"] == "106"


def test_parse_capture_rejects_garbage() -> None:
    cap = parse_capture(["# fap-vbus-capture 1 ports=2 baud=0 echo=0 seed=0",
                         "12 0 01 ff", "# collision t=20 ports=0,1"])
    assert cap.records[0].data == b"\x01\xff"
    assert cap.events[0].kind == "collision" and cap.events[0].t_us == 20
    for bad in (["12 0 1ff"], ["x 0 01"], ["12 0"], ["# collision ports=0,1"],
                ["# fap-vbus-capture 2"]):
        with pytest.raises(CaptureFormatError):
            parse_capture(bad)
    assert issubclass(CaptureFormatError, InvalidValueError)


def test_bad_arguments_and_closed_bus(tmp_path: Path) -> None:
    for kwargs in ({"ports": 1}, {"ports": 65}, {"ports": "3"}, {"baud": -1}, {"seed": 1.5}):
        with pytest.raises(InvalidValueError):
            VirtualBus(**kwargs)
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(PortError) as info:
        VirtualBus(ports=2, link_dir=blocker / "sub")
    assert info.value.errno == errno.ENOTDIR
    bus = VirtualBus(ports=2)
    with pytest.raises(InvalidValueError):
        bus.set_fault(2, bit_error_rate=0.1)
    with pytest.raises(InvalidValueError):
        bus.set_fault(0, drop_rate=1.5)
    with pytest.raises(InvalidValueError):
        bus.drop_next(0, -1)
    with pytest.raises(InvalidValueError):
        bus.silence(0, -1)
    bus.close()
    bus.close()
    with pytest.raises(ClosedError):
        assert bus.stats is None
    with pytest.raises(FapError):
        bus.drop_next(0, 1)
