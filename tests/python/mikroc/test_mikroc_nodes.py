"""A mikroC master and two slaves (0x12 and 150) over the virtual bus,
through fap_py.mikroc (the C nodes underneath)."""
from __future__ import annotations

import threading

import pytest

from fap_py import RS485, RS485Mode
from fap_py.errors import ClosedError, FapTimeoutError, FrameError, InvalidValueError, PortError
from fap_py.mikroc import (
    BROADCAST,
    Master,
    Message,
    MikrocFrameError,
    Slave,
    encode,
)
from fap_py.vbus import VirtualBus

# the addresses of the slaves of the `net` fixture (conftest.py)
SLAVE_A = 0x12
SLAVE_B = 150          # travels escaped; takes no broadcast


def exchange(net, slave, request: bytes, reply: bytes) -> Message:
    net.master.send(slave.address, request)
    got = slave.receive(timeout=5)
    assert got == Message(slave.address, request, True)
    slave.send(reply)
    return net.master.receive(timeout=5)


def test_data_both_ways(net):
    assert (net.a.address, net.b.address) == (SLAVE_A, SLAVE_B)
    assert exchange(net, net.a, b"\x01\x02", b"\x03") == Message(SLAVE_A, b"\x03", False)
    assert exchange(net, net.b, b"\x96\xa9\x00", b"\xa9\x96") == Message(SLAVE_B, b"\xa9\x96", False)
    assert exchange(net, net.a, b"", b"") == Message(SLAVE_A, b"", False)


def test_request_helper(net):
    done = threading.Event()

    def slave_a() -> None:
        msg = net.a.receive(timeout=5)
        net.a.send(bytes(b + 1 for b in msg.data))
        done.set()

    t = threading.Thread(target=slave_a)
    t.start()
    try:
        assert net.master.request(SLAVE_A, b"\x01\x02\x03", timeout=5) == \
            Message(SLAVE_A, b"\x02\x03\x04", False)
    finally:
        t.join(10)
    assert done.is_set()


def test_broadcast_reaches_slaves_but_150(net):
    net.master.send(BROADCAST, b"\x55")
    assert net.a.receive(timeout=5) == Message(BROADCAST, b"\x55", True)
    # slave 150 skips it: the next frame it takes is the one sent after
    net.master.send(SLAVE_B, b"\x66")
    assert net.b.receive(timeout=5) == Message(SLAVE_B, b"\x66", True)
    assert net.b.stats.ignored >= 1


@pytest.mark.direct_only("through the daemon a send is a transaction with a reply window "
                         "(its --timeout), so sends nobody answers hold the bus in turn")
def test_frames_for_other_addresses_never_ready(net):
    for address in range(0, 256, 5):
        if address not in (SLAVE_A, SLAVE_B, BROADCAST):
            net.master.send(address, b"\x01\x02\x03")
    net.master.send(SLAVE_A, b"\xaa")
    net.master.send(SLAVE_B, b"\xbb")
    assert net.a.receive(timeout=5).data == b"\xaa"
    assert net.b.receive(timeout=5).data == b"\xbb"
    for s in (net.a, net.b):
        st = s.stats
        assert st.frames == 1 and st.errors == 0
        assert st.ignored >= 49
    with pytest.raises(FapTimeoutError):
        net.a.receive(timeout=0)


def write_corrupted(net, frame: bytes, at: int) -> None:
    """Send `frame` from the raw port with byte `at` damaged on the wire."""
    net.raw.write(frame[:at])
    net.raw.wait_for(frame[:at])                     # echo: the relay passed them
    net.bus.corrupt_next(net.raw_index, 1)
    net.raw.write(frame[at:])


@pytest.mark.direct_only("through the daemon a send is a transaction with a reply window "
                         "(its --timeout), so sends nobody answers hold the bus in turn")
def test_corrupted_request_sets_slave_error(net):
    # a master frame for 0x12 whose DATA1 is hit (0x01: no flip makes a marker)
    write_corrupted(net, encode(SLAVE_A, b"\x01\x02"), 3)
    with pytest.raises(MikrocFrameError) as info:
        net.a.receive(timeout=5)
    assert isinstance(info.value, FrameError)
    # never delivered, and the other slave saw nothing for itself
    net.master.send(SLAVE_B, b"\x01")
    assert net.b.receive(timeout=5).data == b"\x01"
    assert net.b.stats.errors == 0
    assert net.a.stats.frames == 0
    # the bus works on
    assert exchange(net, net.a, b"\x07", b"\x08").data == b"\x08"


def test_corrupted_reply_sets_master_error(net):
    net.master.send(SLAVE_B, b"\x01")
    assert net.b.receive(timeout=5).data == b"\x01"
    # the "reply" of slave 150 comes damaged from the raw port
    write_corrupted(net, encode(SLAVE_B, b"\x21\x42", from_master=False), 4)
    with pytest.raises(MikrocFrameError):
        net.master.receive(timeout=5)
    assert net.master.stats.errors == 1
    assert exchange(net, net.b, b"\x02", b"\x03").data == b"\x03"


def test_timeouts_and_bad_input(net):
    with pytest.raises(FapTimeoutError):
        net.master.receive(timeout=0.02)
    with pytest.raises(InvalidValueError):
        net.master.send(SLAVE_A, b"\x01\x02\x03\x04")      # refused, nothing sent
    with pytest.raises(InvalidValueError):
        net.a.send(b"\x01\x02\x03\x04")
    with pytest.raises(InvalidValueError):
        net.master.send(300, b"")
    with pytest.raises(InvalidValueError):
        net.master.receive(timeout=-1)
    # nothing went out: slave 0x12's next frame is this one
    net.master.send(SLAVE_A, b"\x09")
    assert net.a.receive(timeout=5).data == b"\x09"


@pytest.mark.direct_only("through the daemon every send has its reply slot: the reply 'nobody "
                         "reads' here is the first send's answer, which receive returns first")
def test_master_send_discards_stale_input(net):
    net.master.send(SLAVE_A, b"\x01")
    net.a.receive(timeout=5)
    stale = encode(SLAVE_A, b"\x99", from_master=False)
    half = encode(SLAVE_A, b"\x98", from_master=False)[:4]
    net.a.send(b"\x99")                    # a reply nobody reads ...
    net.raw.write(half)                    # ... and half a frame
    # both have passed the relay (which serves port 0 before port 3)
    net.raw.wait_for(stale, half)
    net.master.send(SLAVE_A, b"\x02")      # ... are gone when the next request goes out
    assert net.a.receive(timeout=5).data == b"\x02"
    net.a.send(b"\x03")
    assert net.master.receive(timeout=5) == Message(SLAVE_A, b"\x03", False)
    assert net.master.stats.errors == 0


def test_close_ends_a_blocked_receive(net):
    result = []

    def wait() -> None:
        try:
            net.a.receive(timeout=None)
        except ClosedError as exc:
            result.append(exc)

    t = threading.Thread(target=wait)
    t.start()
    net.a.close()
    t.join(10)
    assert not t.is_alive()
    assert len(result) == 1 or net.a.closed
    assert net.a.closed
    with pytest.raises(ClosedError):
        net.a.receive(timeout=0)
    net.a.close()                          # idempotent


def test_open_errors(tmp_path):
    with pytest.raises(PortError):
        Master(str(tmp_path / "no-such-port"), 19200)
    with pytest.raises(InvalidValueError):
        Slave(str(tmp_path / "x"), 19200, address=256)


def test_port_options():
    with VirtualBus(ports=2) as bus:
        with Master(bus.paths[0], 115200, rs485=RS485(mode=RS485Mode.NONE)) as m, \
                Slave(bus.paths[1], 115200, address=3, rs485=RS485(mode=RS485Mode.NONE)) as s:
            m.send(3, b"\x01")
            assert s.receive(timeout=5).data == b"\x01"
        # a pty has no kernel RS-485: an explicit request fails clearly
        with pytest.raises(PortError):
            Master(bus.paths[0], 115200, rs485=RS485(mode=RS485Mode.KERNEL))
        with pytest.raises(InvalidValueError):
            Master(bus.paths[0], 115200, rs485="kernel")
        with pytest.raises(InvalidValueError):
            Master(bus.paths[0], 0)


@pytest.mark.direct_only("through the daemon receive with no request outstanding raises at once "
                         "(docs/daemon.md): there is no waiting receive to race a send")
def test_master_send_while_another_thread_receives(net):
    """A receiving thread does not block send (no deadlock)."""
    got = []
    t = threading.Thread(target=lambda: got.append(net.master.receive(timeout=5)))
    t.start()
    net.master.send(SLAVE_A, b"\x31")          # must not wait for the receive
    assert net.a.receive(timeout=5).data == b"\x31"
    net.a.send(b"\x32")
    t.join(10)
    assert got == [Message(SLAVE_A, b"\x32", False)]


def test_port_that_vanishes_raises_port_error(net):
    net.bus.disconnect(1, 0.3)
    with pytest.raises(PortError):
        net.a.receive(timeout=5)
