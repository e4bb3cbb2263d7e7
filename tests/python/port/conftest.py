"""Fixtures of the port tests: a virtual bus served by ser2net (tcp:// and rfc2217://)."""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Iterator, Tuple

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))   # net_helpers.py
from net_helpers import Ser2net

from fap_py.vbus import VirtualBus


@pytest.fixture
def served(tmp_path: Path) -> Iterator[Tuple[VirtualBus, Ser2net]]:
    """A 3-port virtual bus: port 0 served raw (``urls[0]``), port 1 as
    RFC 2217 (``urls[1]``); port 2 is the test's own."""
    with VirtualBus(ports=3) as bus, \
            Ser2net(tmp_path, [("raw", bus.paths[0], 115200),
                               ("rfc2217", bus.paths[1], 115200)]) as s:
        yield bus, s
