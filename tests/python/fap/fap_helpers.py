"""Helpers of the FAP tests: slave processes driven over stdin/stdout."""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import List, Optional

HERE = Path(__file__).resolve().parent
SLAVE_SCRIPT = HERE / "fap_slave_proc.py"


class SlaveProcess:
    """A Python FAP slave in its own process (see fap_slave_proc.py).

    Lines it prints are collected by a reader thread; :meth:`expect` waits
    for one with a deadline (no sleeps).
    """

    def __init__(self, path: str, slave_id: int, *extra: str) -> None:
        self.id = slave_id
        self.proc = subprocess.Popen(
            [sys.executable, str(SLAVE_SCRIPT), path, str(slave_id), *extra],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True, bufsize=1)
        self.lines: "queue.Queue[Optional[str]]" = queue.Queue()
        self.seen: List[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def expect(self, prefix: str, timeout: float) -> str:
        """The next line starting with prefix (other lines are kept in seen)."""
        while True:
            try:
                line = self.lines.get(timeout=timeout)
            except queue.Empty:
                raise AssertionError(f"slave {self.id}: no {prefix!r} line within {timeout} s; "
                                     f"seen {self.seen[-5:]}, stderr: {self.stderr_now()}") from None
            if line is None:
                raise AssertionError(f"slave {self.id} exited ({self.proc.wait()}): "
                                     f"{self.stderr_now()}")
            self.seen.append(line)
            if line.startswith(prefix):
                return line

    def stderr_now(self) -> str:
        if self.proc.poll() is None or self.proc.stderr is None:
            return "(running)"
        return self.proc.stderr.read()[-2000:]

    def command(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def kill(self) -> None:
        """Vanish without closing anything (SIGKILL)."""
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)
        self._reader.join(10)          # it saw EOF
        self._close_pipes()

    def _close_pipes(self) -> None:
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if f is not None:
                try:
                    f.close()
                except OSError:
                    pass

    def quit(self, timeout: float = 10.0) -> int:
        if self.proc.poll() is None:
            try:
                self.command("quit")
            except (BrokenPipeError, OSError):
                pass
        try:
            return self.proc.wait(timeout=timeout)
        finally:
            self._reader.join(timeout)
            self._close_pipes()

    def __enter__(self) -> "SlaveProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            try:
                self.quit(timeout=5)
            except subprocess.TimeoutExpired:
                os.kill(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
