"""Fixtures of the mikroC tests: the vectors, a virtual bus with a master,
two slaves and a raw port for writing frames byte by byte."""
from __future__ import annotations

import json
import os
import select
import sys
import termios
import time
import tty
from pathlib import Path
from typing import Iterator, NamedTuple

import pytest

sys.path.append(str(Path(__file__).resolve().parents[1] / "serve"))  # last: never shadows a conftest
from serve_helpers import start_daemon  # the daemon tests' own starter

from fap_py.mikroc import Master, Slave
from fap_py.vbus import VirtualBus

VECTORS = Path(__file__).resolve().parents[2] / "vectors" / "mikroc_rs485.json"

SLAVE_A = 0x12
SLAVE_B = 150          # travels escaped; takes no broadcast


@pytest.fixture(scope="session")
def vectors() -> dict:
    return json.loads(VECTORS.read_text(encoding="utf-8"))


class RawPort:
    """A node that writes and reads plain bytes (to inject frames)."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        termios.tcflush(self.fd, termios.TCIOFLUSH)

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            select.select([], [self.fd], [], 5.0)
            n = os.write(self.fd, view)
            view = view[n:]

    def wait_for(self, *seqs: bytes, timeout: float = 5.0) -> None:
        """Read until every one of ``seqs`` has come by (other traffic is
        skipped): the relay has passed those bytes."""
        end = time.monotonic() + timeout
        seen = b""
        while not all(seq in seen for seq in seqs):
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"{[q.hex() for q in seqs]} never came by (saw {seen.hex()})")
            r, _, _ = select.select([self.fd], [], [], left)
            if r:
                seen += os.read(self.fd, 4096)

    def close(self) -> None:
        os.close(self.fd)


class Net(NamedTuple):
    bus: VirtualBus
    master: Master
    a: Slave
    b: Slave
    raw: RawPort
    raw_index: int


@pytest.fixture(params=["direct", "daemon"])
def net(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Net]:
    """Master on port 0, slaves 0x12 and 150 on ports 1 and 2, a raw port 3.
    Echo is on (a 2-wire bus): every node hears itself too. Each test runs with the
    master on port 0 itself and through ``fap serve --protocol mikroc`` on it
    (``fapd://``); a test that needs the port's own master is ``direct_only``."""
    with VirtualBus(ports=4, echo=True, seed=7) as bus:
        daemon = None
        if request.param == "daemon":
            daemon = start_daemon(str(tmp_path), bus.paths[0], "--baud", "19200", "--timeout", "5",
                                  protocol="mikroc")
        try:
            with Master(daemon.url if daemon else bus.paths[0], 19200) as m, \
                    Slave(bus.paths[1], 19200, address=SLAVE_A) as a, \
                    Slave(bus.paths[2], 19200, address=SLAVE_B) as b:
                raw = RawPort(bus.paths[3])
                try:
                    yield Net(bus, m, a, b, raw, 3)
                finally:
                    raw.close()
        finally:
            if daemon is not None:
                daemon.stop()
