"""The servers bench parts start on 127.0.0.1: ser2net (the network rows,
:mod:`bench.net`) and mosquitto (the bridge benches, ``bench/bridge``).

The bench's own launchers, so that it needs nothing from ``tests/`` (whose
helpers do the same for the tests, with pytest's skips): a missing server
is :data:`SER2NET` / :data:`MOSQUITTO` None, and the caller skips its rows.
"""
from __future__ import annotations

import os
import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

SER2NET = shutil.which("ser2net") or (
    "/usr/sbin/ser2net" if os.access("/usr/sbin/ser2net", os.X_OK) else None)
MOSQUITTO = shutil.which("mosquitto", path=os.environ.get("PATH", "") + ":/usr/sbin:/usr/local/sbin")
WAIT = 10.0   #: upper bound of every wait for a server to come up or go


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listening(port: int) -> bool:
    """Whether something listens on 127.0.0.1:port (read from /proc: no connection made)."""
    want = f":{port:04X}"
    for name in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(name) as f:
                for line in f.readlines()[1:]:
                    parts = line.split()
                    if parts[1].endswith(want) and parts[3] == "0A":
                        return True
        except OSError:
            continue
    return False


class Ser2net:
    """ser2net 4 serving devices: ``entries`` (mode ``"raw"`` or
    ``"rfc2217"``, device, baud); :attr:`ports` their TCP ports on loopback.
    ``options``: more connection options; ``nodelay``: ``tcp(nodelay)``."""

    def __init__(self, workdir: Path, entries: List[Tuple[str, str, int]],
                 options: Optional[Dict[str, Any]] = None, nodelay: bool = False) -> None:
        if SER2NET is None:
            raise RuntimeError("ser2net missing (apt-get install ser2net)")
        self.workdir = Path(workdir)
        self.ports = [free_port() for _ in entries]
        self.config = self.workdir / "ser2net.yaml"
        self.log = self.workdir / "ser2net.log"
        lines = ["%YAML 1.1", "---"]
        tcp = "tcp(nodelay)" if nodelay else "tcp"
        for i, ((mode, dev, baud), port) in enumerate(zip(entries, self.ports)):
            acc = f"{tcp},127.0.0.1,{port}" if mode == "raw" \
                else f"telnet(rfc2217),{tcp},127.0.0.1,{port}"
            lines += [f"connection: &c{i}", f"  accepter: {acc}",
                      f"  connector: serialdev,{dev},{baud}n81,local",
                      "  options:", "    kickolduser: true"]
            lines += [f"    {k}: {v}" for k, v in (options or {}).items()] + [""]
        self.config.write_text("\n".join(lines))
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([SER2NET, "-n", "-d", "-c", str(self.config)],
                                         stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + WAIT
        while not all(listening(p) for p in self.ports):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"ser2net did not listen: {self.log.read_text()[-2000:]}")
            time.sleep(0.01)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=WAIT)

    def __enter__(self) -> "Ser2net":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


class Mosquitto:
    """A private mosquitto on a free loopback port with its own config and
    persistence in ``workdir``; ``start()`` / ``stop()`` / ``restart()``, or a
    context manager."""

    def __init__(self, workdir: str, *, port: Optional[int] = None) -> None:
        if MOSQUITTO is None:
            raise RuntimeError("mosquitto missing (apt-get install mosquitto)")
        self.workdir = workdir
        self.port = port or free_port()
        self.proc: Optional[subprocess.Popen[str]] = None
        self.log: List[str] = []
        os.makedirs(os.path.join(workdir, "db"), exist_ok=True)
        lines = [f"listener {self.port} 127.0.0.1", "allow_anonymous true",
                 "persistence true", f"persistence_location {workdir}/db/",
                 "log_dest stderr", "log_type error", "log_type warning", "log_type notice",
                 "log_type information", "max_queued_messages 0", "max_inflight_messages 0"]
        if os.geteuid() == 0:   # as root mosquitto would switch to user "mosquitto": no access here
            lines.append("user root")
        self.conf = os.path.join(workdir, "mosquitto.conf")
        with open(self.conf, "w") as f:
            f.write("\n".join(lines) + "\n")

    def start(self) -> "Mosquitto":
        assert MOSQUITTO is not None
        ready = threading.Event()
        proc = self.proc = subprocess.Popen([MOSQUITTO, "-c", self.conf], stderr=subprocess.PIPE,
                                            stdout=subprocess.DEVNULL, text=True)

        def read() -> None:
            assert proc.stderr is not None
            for line in proc.stderr:
                self.log.append(line.rstrip())
                if " running" in line:
                    ready.set()
            ready.set()   # exited

        threading.Thread(target=read, daemon=True).start()
        if not ready.wait(WAIT) or proc.poll() is not None:
            tail = "\n".join(self.log[-10:])
            self.stop()
            raise RuntimeError(f"mosquitto did not start on port {self.port}:\n{tail}")
        return self

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(WAIT)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def restart(self) -> None:
        self.stop()
        self.start()

    def __enter__(self) -> "Mosquitto":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
