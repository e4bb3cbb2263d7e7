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
sys.path.append(str(HERE.parent / "serve"))  # last: never shadows a conftest
from serve_helpers import start_daemon  # noqa: E402  (the daemon tests' own starter)

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


@pytest.fixture(params=["direct", "daemon"])
def net(request: pytest.FixtureRequest, bus: VirtualBus, tmp_path: Path) -> Iterator[Tuple[Master, List[Slave]]]:
    """A master on port 0 and slaves 3, 7, 31 on ports 1..3, all active. Each test runs
    with the master on port 0 itself and as a client of ``fap serve --protocol fap
    --slaves 3,7,31`` on it (``fapd://``: the daemon's engine, its own timing); a test
    that needs the port's own master is ``direct_only``."""
    slaves: List[Slave] = []
    master = None
    try:
        for i, sid in enumerate(SLAVE_IDS, 1):
            slaves.append(Slave(bus.paths[i], 115200, id=sid))
        if request.param == "daemon":   # after the slaves: the first ID query finds them
            daemon = start_daemon(str(tmp_path), bus.paths[0], "--slaves", ",".join(map(str, SLAVE_IDS)),
                                  protocol="fap")
            request.addfinalizer(daemon.stop)
            master = Master(daemon.url, 115200, slaves=SLAVE_IDS)
        else:
            master = Master(bus.paths[0], 115200, slaves=SLAVE_IDS, **FAST)
        master.wait_active(timeout=WAIT)
        yield master, slaves
    finally:
        for s in slaves:
            s.close()
        if master is not None:
            master.close()
