"""Fixtures of the virtual bus tests."""
from __future__ import annotations

import os
from typing import Iterator, List

import pytest
from vbus_helpers import open_port

from fap_py.vbus import VirtualBus


@pytest.fixture
def open_nodes() -> Iterator:
    """open_nodes(bus) -> one raw fd per port, closed after the test."""
    fds: List[int] = []

    def _open(bus: VirtualBus) -> List[int]:
        opened = [open_port(p) for p in bus.paths]
        fds.extend(opened)
        return opened

    yield _open
    for fd in fds:
        try:
            os.close(fd)
        except OSError:
            pass
