"""Fixtures of the fap_py FAP tests: a virtual bus, fast protocol timing, nodes."""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Dict, Iterator, List, Tuple

import pytest

from fap_py import EventKind, Master, Slave, SlaveEvent
from fap_py.fap import Node
from fap_py.vbus import VirtualBus

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))     # fap_helpers.py

#: Protocol timing in milliseconds instead of the vendor's seconds, so "a
#: slave disappears and returns" runs in well under a second. The answer
#: window and DATA_DONE limit leave room for a loaded CI machine.
FAST: Dict[str, float] = {"id_cycle": 0.05, "id_answer_timeout": 0.05, "data_done_timeout": 0.5}
WAIT = 10.0    #: upper bound of every wait in the tests (never a sleep)
SLAVE_IDS = (3, 7, 31)


def wait_for_event(node: Node, kind: EventKind, node_id: int) -> SlaveEvent:
    """Read events until one of kind about node_id comes (others are skipped:
    on a loaded machine a slave may also miss a short deadline spuriously)."""
    deadline = time.monotonic() + WAIT
    while True:
        ev = node.wait_event(timeout=max(0.0, deadline - time.monotonic()))
        if ev.kind is kind and ev.id == node_id:
            return ev


@pytest.fixture
def bus() -> Iterator[VirtualBus]:
    """An unpaced 4-port virtual bus."""
    with VirtualBus(ports=4) as b:
        yield b


@pytest.fixture
def net(bus: VirtualBus) -> Iterator[Tuple[Master, List[Slave]]]:
    """A master on port 0 and slaves 3, 7, 31 on ports 1..3, all active."""
    slaves: List[Slave] = []
    master = Master(bus.paths[0], 115200, slaves=SLAVE_IDS, **FAST)
    try:
        for i, sid in enumerate(SLAVE_IDS, 1):
            slaves.append(Slave(bus.paths[i], 115200, id=sid))
        master.wait_active(timeout=WAIT)
        yield master, slaves
    finally:
        for s in slaves:
            s.close()
        master.close()
