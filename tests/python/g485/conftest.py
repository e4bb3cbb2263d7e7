"""Shared fixtures of the G485 tests: vectors, pty links and the virtual bus."""
from __future__ import annotations

import json
import os
import tty
from pathlib import Path
from typing import Iterator, List, Tuple

import pytest

VECTORS = Path(__file__).resolve().parents[2] / "vectors" / "g485.json"

@pytest.fixture(scope="session")
def vectors() -> List[dict]:
    """The byte-exact frames of tests/vectors/g485.json."""
    with open(VECTORS, encoding="utf-8") as f:
        return json.load(f)["valid"]


@pytest.fixture
def pty_link() -> Iterator[Tuple[str, int]]:
    """A raw pty pair: (path for the master, fd for the simulator)."""
    mfd, sfd = os.openpty()
    tty.setraw(mfd)
    tty.setraw(sfd)
    try:
        yield os.ttyname(sfd), mfd
    finally:
        os.close(sfd)
        try:
            os.close(mfd)
        except OSError:
            pass


@pytest.fixture
def vbus():
    """A 3-port virtual bus (port 0: master, 1 and 2: simulators), unpaced, seeded."""
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=3, seed=7) as bus:
        yield bus
