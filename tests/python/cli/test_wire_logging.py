"""Wire bytes at DEBUG on fap_py.wire.{fap,exec,mikroc} (C trace hooks, fap_py._trace)."""
from __future__ import annotations

import logging
import threading
from typing import Iterator, List

import pytest

from fap_py import RS485, RS485Mode, execasync, mikroc
from fap_py import Master as FapMaster
from fap_py import Slave as FapSlave
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)
WAIT = 10.0


class Records(logging.Handler):
    """Collects records; `wait(pred)` blocks until one matches (no sleeps)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: List[logging.LogRecord] = []
        self.cond = threading.Condition()

    def emit(self, record: logging.LogRecord) -> None:
        with self.cond:
            self.records.append(record)
            self.cond.notify_all()

    def wait(self, pred, timeout: float = WAIT) -> logging.LogRecord:
        with self.cond:
            found: List[logging.LogRecord] = []

            def match() -> bool:
                found[:] = [r for r in self.records if pred(r)]
                return bool(found)

            assert self.cond.wait_for(match, timeout), [r.getMessage() for r in self.records]
            return found[0]


@pytest.fixture
def wire() -> Iterator[Records]:
    h = Records()
    log = logging.getLogger("fap_py.wire")
    old = log.level
    log.addHandler(h)
    log.setLevel(logging.DEBUG)
    try:
        yield h
    finally:
        log.removeHandler(h)
        log.setLevel(old)


def test_fap_frames_logged_with_wire_bytes(wire: Records) -> None:
    from fap_py.fap import Node  # noqa: F401 - the module under test
    with VirtualBus(ports=2) as bus, FapSlave(bus.paths[1], id=3, rs485=LINE) as s, \
            FapMaster(bus.paths[0], slaves=[3], id_cycle=0.05, rs485=LINE) as m:
        m.wait_active(timeout=WAIT)
        m.send(b"hello", 3)
        assert s.recv(timeout=WAIT).data == b"hello"
        # the master's DATA frame, as sent and as the slave received it
        tx = wire.wait(lambda r: r.name == "fap_py.wire.fap" and r.wire_dir == "tx"
                       and b"hello" in r.wire_bytes)
        rx = wire.wait(lambda r: r.name == "fap_py.wire.fap" and r.wire_dir == "rx"
                       and b"hello" in r.wire_bytes)
    assert tx.wire_bytes == rx.wire_bytes
    assert tx.wire_bytes.startswith(b"cCtRsFeF") and len(tx.wire_bytes) == 15 + 5
    assert tx.wire_status == rx.wire_status == "ok"
    assert tx.levelno == logging.DEBUG and tx.wire_t_ns > 0
    assert tx.getMessage().endswith(tx.wire_bytes.hex(" "))
    # the very first frame (the master's first QUERY_ID) is there: hook set before start
    first = [r for r in wire.records if r.wire_dir == "tx" and bus.paths[0] in r.getMessage()][0]
    assert first.wire_bytes[10] == 3    # msg QUERY_ID


def test_fap_bad_frame_flagged(wire: Records) -> None:
    import serial

    with VirtualBus(ports=2) as bus, FapSlave(bus.paths[1], id=3, rs485=LINE):
        good = bytes.fromhex("63 43 74 52 73 46 65 46 0d 00 03 03 00 75 3c")  # QUERY_ID to 3
        bad = good[:-1] + bytes([good[-1] ^ 0xFF])
        with serial.Serial(bus.paths[0]) as raw:
            raw.write(bad)
            rec = wire.wait(lambda r: r.wire_dir == "rx" and r.wire_status == "bad_crc")
    assert rec.wire_bytes == bad


def test_exec_and_mikroc_wire_bytes(wire: Records) -> None:
    with VirtualBus(ports=2) as bus:
        with execasync.Slave(bus.paths[1], node=4, handler=lambda q: q.data, rs485=LINE).start(), \
                execasync.Master(bus.paths[0], rs485=LINE, timeout=WAIT, retries=0) as em:
            assert em.transact(4, b"\x10ab") == b"\x10ab"
        frame = execasync.encode(4, b"\x10ab", 0)   # the echo reply has the same bytes
        recs = [(r.wire_dir, r.wire_bytes, r.wire_status) for r in wire.records
                if r.name == "fap_py.wire.exec"]
        # master: tx request, rx reply; slave: rx request, tx reply (two threads: any order)
        assert sorted(recs) == sorted([("tx", frame, "ok")] * 2 + [("rx", frame, "ok")] * 2), recs
        with mikroc.Slave(bus.paths[1], address=5, rs485=LINE) as ms, \
                mikroc.Master(bus.paths[0], rs485=LINE) as mm:
            mm.send(5, b"ab")
            assert ms.receive(WAIT).data == b"ab"
        sent = mikroc.encode(5, b"ab")
        wire.wait(lambda r: r.name == "fap_py.wire.mikroc" and r.wire_dir == "tx"
                  and r.wire_bytes == sent)
        wire.wait(lambda r: r.name == "fap_py.wire.mikroc" and r.wire_dir == "rx"
                  and r.wire_bytes == sent and r.wire_status == "ok")


def test_no_hook_without_debug() -> None:
    log = logging.getLogger("fap_py.wire")
    old = log.level
    log.setLevel(logging.INFO)
    try:
        with VirtualBus(ports=2) as bus, execasync.Master(bus.paths[0], rs485=LINE) as em, \
                FapSlave(bus.paths[1], id=3, rs485=LINE) as s:
            assert em._tap is None and s._tap is None     # nothing installed: zero cost
    finally:
        log.setLevel(old)
