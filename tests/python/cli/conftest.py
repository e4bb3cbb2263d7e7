"""Fixtures of the `fap` command tests: run it in-process or as a process."""
from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from typing import Iterator, List

import pytest

from fap_py.vbus import VirtualBus


@dataclass
class Result:
    code: int
    out: str
    err: str

    def lines(self) -> List[str]:
        return self.out.splitlines()


@pytest.fixture
def fap(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch):
    """fap(*args) -> Result, through fap_py.cli.main (the console entry point)."""
    from fap_py.cli import main

    monkeypatch.setenv("COLUMNS", "100")

    def run(*args: str) -> Result:
        code = main(list(args))
        cap = capsys.readouterr()
        return Result(code, cap.out, cap.err)

    return run


def fap_cmd(*args: str) -> List[str]:
    """argv of the installed command as a process (-I: not the source tree)."""
    return [sys.executable, "-I", "-m", "fap_py", *args]


def run_proc(*args: str, timeout: float = 60, **kw) -> Result:
    env = dict(os.environ, COLUMNS="100")
    p = subprocess.run(fap_cmd(*args), capture_output=True, text=True, timeout=timeout,
                       env=env, **kw)
    return Result(p.returncode, p.stdout, p.stderr)


@pytest.fixture
def bus() -> Iterator[VirtualBus]:
    with VirtualBus(ports=3) as b:
        yield b
