"""The port layer's network transports (tcp://, rfc2217://) against real servers.

ser2net (raw and RFC 2217) and pyserial's RFC 2217 PortManager serve one
port of a virtual bus; the test reads and writes the bus's other port
directly. Every byte value, CR NUL and CR LF pass both ways; bad URLs,
refused connections, refused parameters and RS-485 modes a URL cannot have
give the documented errors.
"""
from __future__ import annotations

import errno
import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import Iterator, Tuple

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from net_helpers import WAIT, FaultProxy, Rfc2217Server, Ser2net, free_port, wait_until

from fap_py import RS485, RS485Mode
from fap_py._native import ffi, lib
from fap_py.errors import InvalidValueError, PortError, PortGoneError
from fap_py.port import Port
from fap_py.vbus import VirtualBus

#: every byte value, then the sequences a Telnet stack likes to rewrite
PAYLOAD = bytes(range(256)) + b"\r\0\r\n\xff\xff\r" + b"\xff" * 40


@pytest.fixture
def bus() -> Iterator[VirtualBus]:
    with VirtualBus(ports=3) as b:
        yield b


@pytest.fixture
def ser2net(tmp_path: Path, bus: VirtualBus) -> Iterator[Ser2net]:
    """Port 0 of the bus raw, port 1 as RFC 2217; port 2 is the test's own."""
    with Ser2net(tmp_path, [("raw", bus.paths[0], 115200),
                            ("rfc2217", bus.paths[1], 115200)]) as s:
        yield s


def read_exactly(port: Port, n: int) -> bytes:
    got = b""
    deadline = time.monotonic() + WAIT
    while len(got) < n and time.monotonic() < deadline:
        got += port.read(n - len(got), timeout=0.2)
    return got


def roundtrip(url: str, local: str) -> Tuple[bytes, bytes]:
    with Port(url, 115200) as net, Port(local, 115200) as dev:
        net.write(PAYLOAD)
        there = read_exactly(dev, len(PAYLOAD))
        dev.write(PAYLOAD[::-1])
        back = read_exactly(net, len(PAYLOAD))
    return there, back


@pytest.mark.parametrize("which", [0, 1], ids=["raw", "rfc2217"])
def test_every_byte_both_ways_through_ser2net(ser2net: Ser2net, bus: VirtualBus,
                                              which: int) -> None:
    there, back = roundtrip(ser2net.urls[which], bus.paths[2])
    assert there == PAYLOAD
    assert back == PAYLOAD[::-1]


def test_every_byte_both_ways_through_pyserial_rfc2217(bus: VirtualBus,
                                                       caplog: pytest.LogCaptureFixture) -> None:
    with Rfc2217Server(bus.paths[0]) as srv, caplog.at_level(logging.WARNING):
        there, back = roundtrip(srv.url, bus.paths[2])
        assert srv.serial.baudrate == 115200      # SET-BAUDRATE reached the serial side
    assert there == PAYLOAD and back == PAYLOAD[::-1]
    # PortManager answers every option: no warning about unanswered ones
    assert not [r for r in caplog.records if "rfc2217" in r.getMessage()]


def test_ser2net_never_answering_control_is_a_warning_not_a_wait(
        ser2net: Ser2net, caplog: pytest.LogCaptureFixture) -> None:
    """ser2net on a pty does not answer the DTR/RTS requests: the baud query
    sent after them (the fence) is answered, so the open goes on at once,
    under the default option_ms of 3 s, with the reason logged (not called
    slow: it answered everything else)."""
    t0 = time.monotonic()
    with caplog.at_level(logging.WARNING, logger="fap_py.port"), Port(ser2net.urls[1], 115200) as p:
        took = time.monotonic() - t0
        note = ffi.new("char[]", 256)
        assert lib.fap_port_warning(p._h, note, 256) > 0
        assert b"does not answer SET-CONTROL" in ffi.string(note)
    assert took < 1.5          # the whole option_ms would be 3 s
    msgs = [r.getMessage() for r in caplog.records if "SET-CONTROL" in r.getMessage()]
    assert msgs and not [m for m in msgs if "option_ms" in m], msgs


def test_refused_baud_is_an_error(bus: VirtualBus) -> None:
    with Rfc2217Server(bus.paths[0], refuse_baud=57600) as srv:
        with pytest.raises(PortError) as ei:
            Port(srv.url, 57600)
        assert "refused" in str(ei.value)
        with Port(srv.url, 115200):               # the same server, a rate it takes
            pass


def test_bad_urls() -> None:
    for url in ("tcp://", "tcp://host", "tcp://host:99999", "tcp://host:0", "tcp://:80",
                "foo://host:1", "tcp://host:1?nonsense=1", "tcp://host:1?rtt_ms=x",
                "tcp://h:0000000000080", "rfc2217://[::1", "tcp://h/x:1"):
        with pytest.raises(InvalidValueError) as ei:
            Port(url, 115200)
        assert url in str(ei.value) and "URL" in str(ei.value)


def test_refused_connection_and_unknown_host() -> None:
    with pytest.raises(PortError) as ei:
        Port(f"tcp://127.0.0.1:{free_port()}", 115200)
    assert ei.value.errno == errno.ECONNREFUSED
    with pytest.raises(PortError) as ei:
        Port("tcp://no-such-host.invalid:4000", 115200)
    assert "host name not resolved" in str(ei.value)


def test_connect_timeout() -> None:
    """A server whose backlog is full never completes the handshake."""
    with socket.socket() as lst:
        lst.bind(("127.0.0.1", 0))
        lst.listen(0)
        port = lst.getsockname()[1]
        fillers = []
        try:
            for _ in range(8):                    # fill the accept queue
                s = socket.socket()
                s.setblocking(False)
                s.connect_ex(("127.0.0.1", port))
                fillers.append(s)
            t0 = time.monotonic()
            with pytest.raises(PortError) as ei:
                Port(f"tcp://127.0.0.1:{port}?connect_ms=200", 115200)
            assert ei.value.errno == errno.ETIMEDOUT
            assert time.monotonic() - t0 < 5.0
        finally:
            for s in fillers:
                s.close()


@pytest.mark.parametrize("mode", [RS485Mode.KERNEL, RS485Mode.SOFT_RTS])
def test_rs485_direction_on_a_url_is_refused(ser2net: Ser2net, mode: RS485Mode) -> None:
    with pytest.raises(InvalidValueError) as ei:
        Port(ser2net.urls[0], 115200, RS485(mode=mode))
    assert "server's" in str(ei.value)


def test_auto_and_none_are_none(ser2net: Ser2net) -> None:
    for mode in (RS485Mode.AUTO, RS485Mode.NONE):
        with Port(ser2net.urls[0], 115200, RS485(mode=mode)) as p:
            assert p.mode is RS485Mode.NONE


@pytest.mark.parametrize("scheme", ["tcp", "rfc2217"])
def test_split_and_delayed_segments_arrive_whole(bus: VirtualBus, scheme: str,
                                                 tmp_path: Path) -> None:
    """Through a proxy that sends every byte as its own segment, late and jittered."""
    upstream: "Ser2net | Rfc2217Server"
    if scheme == "tcp":
        upstream = Ser2net(tmp_path, [("raw", bus.paths[0], 115200)])
        up_port = upstream.ports[0]
    else:
        upstream = Rfc2217Server(bus.paths[0])
        up_port = upstream.port
    try:
        with FaultProxy(up_port) as px:
            px.split, px.delay, px.jitter = True, 0.002, 0.003
            there, back = roundtrip(px.url(scheme), bus.paths[2])
            assert there == PAYLOAD and back == PAYLOAD[::-1]
    finally:
        if isinstance(upstream, Ser2net):
            upstream.stop()
        else:
            upstream.close()


def test_dropped_connection_is_a_vanished_port_and_reopens(bus: VirtualBus) -> None:
    with Rfc2217Server(bus.paths[0]) as srv, FaultProxy(srv.port) as px, \
            Port(px.url("rfc2217"), 115200) as p, Port(bus.paths[2], 115200) as dev:
        px.reset()
        with pytest.raises(PortGoneError):
            wait_until(lambda: p.read(16, timeout=0.05) and False, "the reset", 5)
        px.accepting = False
        with pytest.raises(PortError):
            p.reopen()                            # the server is "down"
        px.accepting = True
        wait_until(lambda: _reopened(p), "the reconnect")
        assert p.stats.reopens >= 1
        p.write(b"after")
        assert read_exactly(dev, 5) == b"after"


def _reopened(p: Port) -> bool:
    try:
        p.reopen()
        return True
    except PortError:
        return False
