"""Helpers of the ``fap sim`` tests: run the command as a process and wait for its ready line."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
from typing import Any, Dict, Iterator, List

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
EXAMPLES = os.path.join(ROOT, "examples", "sim")


def fap_argv(*args: str) -> List[str]:
    return [sys.executable, "-m", "fap_py", *args]


def run(*args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run(fap_argv(*args), capture_output=True, text=True, timeout=timeout)


class Result:
    def __init__(self, returncode: int, stdout: str, stderr: str) -> None:
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def cli(*args: str) -> Result:
    """``fap ARGS`` in this process, through the console entry point (fap_py.cli.main): no
    interpreter start-up per call, so a test of many commands stays fast."""
    import contextlib
    import io

    from fap_py.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(args))
        except SystemExit as exc:       # argparse's usage errors
            code = int(exc.code or 0)
    return Result(code, out.getvalue(), err.getvalue())


class SimProcess:
    """``fap sim CONFIG --json ...`` as a process; :attr:`ready` is its ready event."""

    def __init__(self, *args: str, timeout: float = 8.0) -> None:
        self.proc = subprocess.Popen(fap_argv("sim", *args, "--json"), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        line = self._line(timeout)
        if not line:
            self.proc.kill()
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise AssertionError(f"fap sim did not get ready: {err}")
        self.ready: Dict[str, Any] = json.loads(line)
        assert self.ready["event"] == "ready", line

    def _line(self, timeout: float) -> str:
        assert self.proc.stdout is not None
        r, _, _ = select.select([self.proc.stdout], [], [], timeout)   # waits for the line, not a sleep
        return self.proc.stdout.readline() if r else ""

    def port(self, bus: int = 0) -> str:
        return self.ready["buses"][bus]["master_port"]

    def stop(self, timeout: float = 8.0) -> Dict[str, Any]:
        self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=timeout)
        assert self.proc.returncode == 0, err
        return json.loads(out.strip().splitlines()[-1])

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate(timeout=5)


@pytest.fixture
def sim_process() -> Iterator[Any]:
    made: List[SimProcess] = []

    def start(*args: str) -> SimProcess:
        p = SimProcess(*args)
        made.append(p)
        return p

    yield start
    for p in made:
        p.kill()


@pytest.fixture
def control(tmp_path) -> str:
    # a short path: a Unix socket's is at most 107 bytes
    import tempfile
    d = tempfile.mkdtemp(prefix="fapsim")
    yield f"unix:{d}/c.sock"
    import shutil
    shutil.rmtree(d, ignore_errors=True)
