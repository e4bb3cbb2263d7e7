"""Syscalls and CPU of one bench process over the measuring window (``perf stat``).

Counts do not depend on the machine's load the way CPU time does, so the
bench reports them beside CPU per exchange. ``perf stat`` counts in the
kernel (the ``raw_syscalls:sys_enter`` tracepoint and ``task-clock``, or with
``detail`` one ``syscalls:sys_enter_<name>`` tracepoint per syscall of
``DETAIL``) and
costs the measured process next to nothing.

perf here cannot attach to a running process (``-p`` counts nothing in this
kind of VM), so the probe wraps the command from its start with counting
disabled (``-D -1``) and opens the window through perf's control pipe
(``--control fd:CTL,ACK``): :meth:`Probe.enable` when the client says
"measuring", :meth:`Probe.disable` when it reports. Without perf the probe
wraps nothing and reports nothing; the bench goes on.

perf says ``Events disabled`` / ``Events enabled`` on its stderr at every
switch of the window: the wrapped command's stderr goes to a file
(:attr:`Probe.stderr`) and :meth:`Probe.relay_stderr` passes on every other
line (the command's own errors, perf's real ones).
"""
from __future__ import annotations

import logging
import os
import re
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import IO, Dict, List, Optional

log = logging.getLogger("bench.syscalls")
# The syscalls an exchange can make (the rest is reported as "other"): a
# tracepoint each; all ~360 would take perf seconds to close (an RCU grace
# period per event).
DETAIL = ("read", "write", "epoll_wait", "epoll_pwait", "epoll_ctl", "timerfd_settime",
          "ioctl", "poll", "ppoll", "pselect6", "select", "futex", "clock_nanosleep",
          "nanosleep", "fcntl", "clock_gettime", "sched_yield", "getrusage", "epoll_pwait2")
_PERF: Optional[bool] = None
#: perf's own notes on the control pipe's switches: not errors, never shown
NOISE = re.compile(r"^Events (enabled|disabled)\s*$")


def have_perf() -> bool:
    """perf is installed and counts syscall tracepoints here (cached)."""
    global _PERF
    if _PERF is None:
        _PERF = False
        if shutil.which("perf"):
            r = subprocess.run(["perf", "stat", "-x,", "-e", "raw_syscalls:sys_enter", "true"],
                               capture_output=True, text=True)
            _PERF = r.returncode == 0 and re.search(r"^\d+,", r.stderr, re.M) is not None
    return _PERF


class Probe:
    """perf stat around one command, counting only between enable and disable."""

    def __init__(self, detail: bool = False) -> None:
        self.detail = detail
        self.on = have_perf()
        self.window = 0.0
        self._t = 0.0
        self._out = Path(tempfile.mkstemp(prefix="bench-perf-", suffix=".csv")[1])
        self._ctl_r, self._ctl_w = os.pipe()
        self._ack_r, self._ack_w = os.pipe()
        self._err: Optional[IO[bytes]] = tempfile.TemporaryFile() if self.on else None

    @property
    def stderr(self) -> Optional[IO[bytes]]:
        """The wrapped command's stderr (``Popen(stderr=...)``): a file
        when perf wraps it, None (inherit) otherwise."""
        return self._err

    def relay_stderr(self, to: Optional[IO[str]] = None) -> None:
        """After the command ended: its stderr lines but perf's switch notes,
        to ``to`` (default sys.stderr). Once; later calls do nothing."""
        if self._err is None:
            return
        self._err.seek(0)
        text = self._err.read().decode(errors="replace")
        self._err.close()
        self._err = None
        kept = [line for line in text.splitlines() if line.strip() and not NOISE.match(line)]
        if kept:
            print("\n".join(kept), file=to or sys.stderr, flush=True)

    @property
    def pass_fds(self) -> List[int]:
        return [self._ctl_r, self._ack_w] if self.on else []

    def wrap(self, argv: List[str]) -> List[str]:
        """argv under perf stat (unchanged without perf)."""
        if not self.on:
            return argv
        events = "raw_syscalls:sys_enter,task-clock"
        if self.detail:
            events += "".join(f",syscalls:sys_enter_{n}" for n in DETAIL)
        return ["perf", "stat", "-x,", "-D", "-1", "--control",
                f"fd:{self._ctl_r},{self._ack_w}", "-o", str(self._out), "-e", events,
                "--"] + argv

    def started(self) -> None:
        """The wrapped command runs: drop our copies of perf's pipe ends, so
        a perf that died reads as end of file instead of a hang."""
        for fd in (self._ctl_r, self._ack_w):
            os.close(fd)
        self._ctl_r = self._ack_w = -1

    def _command(self, word: str) -> None:
        if not self.on:
            return
        try:
            os.write(self._ctl_w, word.encode() + b"\n")
        except BrokenPipeError:
            self.on = False
            return
        ready, _, _ = select.select([self._ack_r], [], [], 5.0)
        if not ready or not os.read(self._ack_r, 16):      # "ack": switched
            log.warning("perf did not acknowledge %s: no syscall counts", word)
            self.on = False

    def enable(self) -> None:
        self._command("enable")
        self._t = time.monotonic()

    def disable(self) -> None:
        self._command("disable")
        self.ended()

    def ended(self) -> None:
        """The window ends now (a command that exits ends its counting itself)."""
        self.window = time.monotonic() - self._t

    def result(self) -> Optional[Dict[str, float]]:
        """After the command ended: per second of the window, ``syscalls``,
        ``cpu`` (s/s) and with ``detail`` each syscall by name. None without
        perf or when it wrote nothing."""
        for fd in (self._ctl_r, self._ctl_w, self._ack_r, self._ack_w):
            if fd >= 0:
                os.close(fd)
        if not self.on or self.window <= 0:
            self._out.unlink(missing_ok=True)
            return None
        text = self._out.read_text() if self._out.exists() else ""
        self._out.unlink(missing_ok=True)
        counts = parse_stat(text)
        if "syscalls" not in counts:
            log.debug("perf gave nothing: %s", text[-300:])
            return None
        return {k: v / self.window for k, v in counts.items()}


def parse_stat(text: str) -> Dict[str, float]:
    """``perf stat -x,`` lines (value,unit,event,...) -> syscalls, cpu (s) and
    the nonzero ``syscalls:sys_enter_<name>`` counts by name."""
    out: Dict[str, float] = {}
    per_name = 0.0
    for line in text.splitlines():
        f = line.split(",")
        if len(f) < 3 or not re.match(r"^[0-9.]+$", f[0]):
            continue
        v, ev = float(f[0]), f[2]
        if ev == "raw_syscalls:sys_enter":
            out["syscalls"] = v
        elif ev == "task-clock":
            out["cpu"] = v / 1e3                  # msec
        elif ev.startswith("syscalls:sys_enter_") and v:
            out[ev[len("syscalls:sys_enter_"):]] = v
            per_name += v
    if "syscalls" in out and per_name and out["syscalls"] > per_name:
        out["other"] = out["syscalls"] - per_name
    return out
