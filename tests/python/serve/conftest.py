"""Fixtures of the daemon tests: a paced virtual bus (115200 baud): port 0 the daemon's,
port 1 an exec async slave node 5 (echoes), port 2 a spy that sees the wire, port 3
slave node 6 (echoes when the test opens its gate: a late reply)."""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Iterator, List

import pytest
import serial
from serve_helpers import Served, start_daemon

from fap_py.execasync import RS485, Decoder, Frame, RS485Mode, Slave
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)   # ptys have no RS-485 ioctls


@dataclass
class Bus:
    bus: VirtualBus
    spy: serial.Serial
    late_gate: threading.Event = field(default_factory=threading.Event)
    hold: threading.Event = field(default_factory=threading.Event)

    @property
    def master_port(self) -> str:
        return self.bus.paths[0]

    def spy_frames(self, quiet: float = 0.05) -> List[Frame]:
        dec = Decoder()
        frames: List[Frame] = []
        self.spy.timeout = quiet
        while True:
            chunk = self.spy.read(4096)
            if not chunk:
                return frames
            frames += dec.feed(chunk)


@pytest.fixture
def vbus() -> Iterator[Bus]:
    with VirtualBus(ports=4, baud=115200) as bus:
        b = Bus(bus, serial.Serial(bus.paths[2], 115200, timeout=0.05))
        b.late_gate.set()

        def slow(req):
            b.hold.set()                    # the test sees the request arrived ...
            b.late_gate.wait(5)             # ... and says when the answer goes
            return req.data

        with Slave(bus.paths[1], node=5, handler=lambda req: req.data, rs485=LINE) as s5, \
                Slave(bus.paths[3], node=6, handler=slow, rs485=LINE) as s6:
            s5.start()
            s6.start()
            yield b
            b.late_gate.set()
        b.spy.close()


@pytest.fixture
def served(vbus: Bus, tmp_path) -> Iterator[Served]:
    d = start_daemon(str(tmp_path), vbus.master_port)
    yield d
    d.stop()
