"""A hot-unplug under the daemon, every protocol besides exec (test_exec_clients.py has
exec's): the adapter is pulled out, the next transaction fails with the port-gone error a
direct master would raise, every client is told (``port_gone``, ``port_back``), the
daemon reopens the port by itself and the same client transacts again. FAP's engine
reopens its port itself: the daemon's state and counters follow its events, and a FAP
client gets PORT_LOST / PORT_REOPENED as a direct master does."""
from __future__ import annotations

from typing import Any, Callable, List

import pytest
from serve_helpers import Served, fap_echo, mikroc_echo, start_daemon

from fap_py import mikroc
from fap_py.errors import FapTimeoutError, PortGoneError
from fap_py.execasync import RS485, RS485Mode
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)


def _events(conn: Any) -> List[str]:
    out = []
    while (ev := conn.next_event(0)) is not None:
        out.append(ev["event"])
    return out


def _pull_and_wait(bus: VirtualBus, d: Served, call: Callable[[], Any]) -> None:
    """Pull the daemon's adapter out; ``call`` fails with PortGoneError within 50 tries
    (the first write or read after it), the daemon says gone, then reopens."""
    bus.disconnect(0, 1.0)
    with pytest.raises(PortGoneError):
        for _ in range(50):
            try:
                call()
            except FapTimeoutError:
                continue              # a transaction that was on the wire as it went
    st = d.status()
    assert st["daemon"]["port_state"] == "gone" and st["totals"]["port_gone"] == 1
    d.wait_for(lambda st: st["daemon"]["port_state"] == "open")


def test_mikroc_clients_are_told_and_the_port_reopened(tmp_path):
    with VirtualBus(ports=2, baud=19200) as bus, mikroc_echo(bus.paths[1]):
        d = start_daemon(str(tmp_path), bus.paths[0], "--baud", "19200", "--timeout", "0.3",
                         protocol="mikroc")
        try:
            with mikroc.Master(d.url) as m:
                assert m.request(0x12, b"\x01\x02", timeout=1.0).data == b"\x02\x01"
                _pull_and_wait(bus, d, lambda: m.request(0x12, b"\x03", timeout=0.05))
                assert m.request(0x12, b"\x04\x05", timeout=1.0).data == b"\x05\x04"
                assert d.status()["totals"]["reopens"] == 1
                assert _events(m._conn) == ["port_gone", "port_back"]
        finally:
            d.stop()


def test_g485_clients_are_told_and_the_port_reopened(tmp_path):
    from fap_py.g485 import G485Master
    from fap_py.g485.device import SimDevice
    from fap_py.g485.simulator import Simulator

    with VirtualBus(ports=2, baud=115200) as bus, Simulator(bus.paths[1], [SimDevice(3)], rs485=LINE):
        d = start_daemon(str(tmp_path), bus.paths[0], "--timeout", "0.3", "--retries", "0",
                         protocol="g485")
        try:
            with G485Master(d.url) as m:
                m.write(3, 10, b"\x2a")
                _pull_and_wait(bus, d, lambda: m.read(3, 10, timeout=0.05, retries=0))
                assert m.read(3, 10, timeout=1.0) == b"\x2a"
                assert d.status()["totals"]["reopens"] == 1
                assert _events(m._conn) == ["port_gone", "port_back"]
        finally:
            d.stop()


def test_fap_clients_are_told_and_the_engine_polls_again(tmp_path):
    from fap_py import Master
    from fap_py.fap import EventKind

    with VirtualBus(ports=2, baud=115200) as bus, fap_echo(bus.paths[1]):
        d = start_daemon(str(tmp_path), bus.paths[0], "--slaves", "3", protocol="fap")
        try:
            with Master(d.url, slaves=[3]) as m:
                m.wait_active([3], timeout=10)
                bus.disconnect(0, 1.0)
                d.wait_for(lambda st: st["totals"]["port_gone"] == 1)
                d.wait_for(lambda st: st["daemon"]["port_state"] == "open")
                assert d.status()["totals"]["reopens"] == 1
                # the client sees the engine's own events, as a direct master would
                kinds = []
                while EventKind.PORT_REOPENED not in kinds:
                    kinds.append(m.wait_event(timeout=10).kind)
                assert EventKind.PORT_LOST in kinds
                assert kinds.index(EventKind.PORT_LOST) < kinds.index(EventKind.PORT_REOPENED)
                m.wait_active([3], timeout=10)
                m.send(b"abc", 3)
                for _ in range(10):              # the answer to ours (earlier ones may come first)
                    msg = m.recv(timeout=10)
                    if msg.data == b"cba":
                        break
                assert (msg.source, msg.data) == (3, b"cba")
        finally:
            d.stop()


def test_raw_clients_are_told_and_the_port_reopened(tmp_path):
    from fap_py.execasync import Decoder, Slave, encode
    from fap_py.serve import Connection

    with VirtualBus(ports=2, baud=115200) as bus, \
            Slave(bus.paths[1], node=5, handler=lambda r: r.data[::-1], rs485=LINE).start():
        d = start_daemon(str(tmp_path), bus.paths[0], protocol="raw")
        try:
            with Connection(d.url, protocol="raw") as c:
                def ask(data: bytes, timeout: float) -> bytes:
                    got = c.call("transact", data=encode(5, data, seq=0).hex(), timeout=timeout,
                                 idle=0.01)
                    return bytes.fromhex(got["data"])

                assert [f.data for f in Decoder().feed(ask(b"ab", 1.0))] == [b"ba"]
                _pull_and_wait(bus, d, lambda: ask(b"x", 0.05))
                assert [f.data for f in Decoder().feed(ask(b"cd", 1.0))] == [b"dc"]
                assert d.status()["totals"]["reopens"] == 1
                assert _events(c) == ["port_gone", "port_back"]
        finally:
            d.stop()
