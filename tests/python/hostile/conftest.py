"""Fixtures of the hostile tests."""
from __future__ import annotations

import os
import pty as _pty
from typing import Iterator, Tuple

import pytest


@pytest.fixture
def pty_pair() -> Iterator[Tuple[int, str]]:
    """A pty pair: the far end's fd (non-blocking; the test reads it, or not) and the path."""
    far, near = _pty.openpty()
    name = os.ttyname(near)
    os.close(near)
    os.set_blocking(far, False)
    yield far, name
    os.close(far)
