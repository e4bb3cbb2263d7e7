"""Fixtures of the hostile tests."""
from __future__ import annotations

import json
import os
import pty as _pty
import subprocess
import sys
from pathlib import Path
from typing import Iterator, Tuple

import pytest

RUNNER = Path(__file__).with_name("walk_runner.py")


@pytest.fixture(scope="session")
def walk_report(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The hostile walk's report (walk_runner.py, in a child process with its own cwd,
    HOME and an empty stdin): findings, and every callable it called with bad values."""
    home = tmp_path_factory.mktemp("walk")
    env = dict(os.environ, HOME=str(home), PYTHONDONTWRITEBYTECODE="1")
    r = subprocess.run([sys.executable, str(RUNNER)], cwd=home, env=env, stdin=subprocess.DEVNULL,
                       capture_output=True, text=True, timeout=540)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.fixture
def pty_pair() -> Iterator[Tuple[int, str]]:
    """A pty pair: the far end's fd (non-blocking; the test reads it, or not) and the path."""
    far, near = _pty.openpty()
    name = os.ttyname(near)
    os.close(near)
    os.set_blocking(far, False)
    yield far, name
    os.close(far)
