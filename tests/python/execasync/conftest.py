"""Fixtures of the exec async tests: a virtual bus with a master on port 0,
slaves for nodes 1..3 on ports 1..3 (each in its own serving thread), a raw
pyserial port 4 to inject frames and a spy port 5 that records the wire."""
from __future__ import annotations

import json
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Iterator, List

import pytest
import serial

sys.path.append(str(Path(__file__).resolve().parents[1] / "serve"))  # last: never shadows a conftest
from serve_helpers import start_daemon  # the daemon tests' own starter

from fap_py.execasync import RS485, Decoder, Frame, Master, Request, RS485Mode, Slave
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)   # ptys have no RS-485 ioctls
VECTORS = Path(__file__).resolve().parents[2] / "vectors" / "exec_async.json"


@pytest.fixture(scope="session")
def vectors() -> dict:
    return json.loads(VECTORS.read_text())


@dataclass
class Counter:
    """What one slave's handler applied (read by the test thread)."""

    node: int
    applied: int = 0
    broadcasts: List[bytes] = field(default_factory=list)
    broadcast_seen: threading.Event = field(default_factory=threading.Event)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def handler(self, req: Request) -> bytes:
        with self.lock:
            if req.broadcast:
                self.broadcasts.append(req.data)
                self.broadcast_seen.set()
                return b""
            self.applied += 1
            return bytes([self.node, self.applied]) + req.data


@dataclass
class Net:
    bus: VirtualBus
    master: Master
    slaves: Dict[int, Slave]
    counters: Dict[int, Counter]
    raw: serial.Serial
    spy: serial.Serial

    def spy_frames(self, quiet: float = 0.03) -> List[Frame]:
        """Every frame the spy saw until `quiet` seconds of silence."""
        dec = Decoder()
        frames: List[Frame] = []
        self.spy.timeout = quiet
        while True:
            chunk = self.spy.read(1)      # pyserial waits for all it is asked for
            if not chunk:
                return frames
            frames += dec.feed(chunk + self.spy.read(self.spy.in_waiting))


def _raw_port(path: str) -> serial.Serial:
    port = serial.Serial(path, baudrate=115200, timeout=0.5)
    port.reset_input_buffer()
    return port


@pytest.fixture(params=["direct", "daemon"])
def net(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Net]:
    """A timeout of 1 s: a loaded machine must not cause retries the tests do
    not expect (a retried seq 0 is processed again, by the settled rule);
    tests that lose a reply on purpose shorten it. Each test runs twice: on the
    port itself and through ``fap serve`` on it (``fapd://``: the same calls,
    results and exceptions); a test that needs the port's own master says so
    with ``@pytest.mark.direct_only(reason)`` and gets no daemon run."""
    with VirtualBus(ports=6) as bus:
        counters = {n: Counter(n) for n in (1, 2, 3)}
        slaves = {n: Slave(bus.paths[n], node=n, handler=counters[n].handler, rs485=LINE).start()
                  for n in (1, 2, 3)}
        daemon = None
        if request.param == "daemon":
            daemon = start_daemon(str(tmp_path), bus.paths[0], "--timeout", "1.0", "--retries", "5")
            master = Master(daemon.url, timeout=1.0, retries=5, rs485=LINE)
        else:
            master = Master(bus.paths[0], timeout=1.0, retries=5, rs485=LINE)
        raw, spy = _raw_port(bus.paths[4]), _raw_port(bus.paths[5])
        try:
            yield Net(bus, master, slaves, counters, raw, spy)
        finally:
            master.close()
            if daemon is not None:
                daemon.stop()
            for s in slaves.values():
                s.close()
                assert s.error is None, s.error
            raw.close()
            spy.close()
