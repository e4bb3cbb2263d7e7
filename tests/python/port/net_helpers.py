"""Servers for the network-transport tests, all on 127.0.0.1 and started by the tests.

* :class:`Ser2net`: Debian's ser2net 4 with a YAML config written here, one
  raw (``tcp://``) and/or one RFC 2217 (``rfc2217://``) accepter per device;
* :class:`Rfc2217Server`: an independent RFC 2217 server, pyserial's
  ``serial.rfc2217.PortManager`` over a pty (optionally refusing a baud rate);
* :class:`FaultProxy`: a TCP proxy that delays, jitters, splits every
  segment into single bytes and resets connections on demand.

ser2net may be missing only outside CI (``need``): with ``CI`` set a missing
tool fails the test instead of skipping it.
"""
from __future__ import annotations

import os
import random
import select
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Tuple

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bridge"))
from bridge_helpers import need

SER2NET = shutil.which("ser2net") or (
    "/usr/sbin/ser2net" if os.access("/usr/sbin/ser2net", os.X_OK) else None)
WAIT = 10.0   #: upper bound of every wait (never a sleep used as synchronisation)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until(cond: Callable[[], Any], what: str, timeout: float = WAIT) -> Any:
    """Poll ``cond`` until it is true (returns its value) or fail after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


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
    """ser2net serving devices: ``entries`` is a list of (mode, device, baud),
    mode ``"raw"`` or ``"rfc2217"``; :attr:`urls` the matching client URLs.
    ``options``: more ser2net connection options (``{"chardelay-min": 100}``);
    ``nodelay``: ser2net's own socket without Nagle (``tcp(nodelay)``)."""

    def __init__(self, workdir: Path, entries: List[Tuple[str, str, int]],
                 options: Optional[Dict[str, Any]] = None, nodelay: bool = False) -> None:
        need("ser2net", SER2NET is not None)
        self.workdir = Path(workdir)
        self.entries = entries
        self.ports = [free_port() for _ in entries]
        self.urls = [("tcp" if mode == "raw" else "rfc2217") + f"://127.0.0.1:{port}"
                     for (mode, _, _), port in zip(entries, self.ports)]
        self.config = self.workdir / "ser2net.yaml"
        self.log = self.workdir / "ser2net.log"
        lines = ["%YAML 1.1", "---"]
        for i, ((mode, dev, baud), port) in enumerate(zip(self.entries, self.ports)):
            tcp = "tcp(nodelay)" if nodelay else "tcp"
            acc = f"{tcp},127.0.0.1,{port}" if mode == "raw" \
                else f"telnet(rfc2217),{tcp},127.0.0.1,{port}"
            lines += [f"connection: &c{i}", f"  accepter: {acc}",
                      f"  connector: serialdev,{dev},{baud}n81,local",
                      "  options:", "    kickolduser: true"]
            lines += [f"    {k}: {v}" for k, v in (options or {}).items()] + [""]
        self.config.write_text("\n".join(lines))
        self.proc: Optional[subprocess.Popen[bytes]] = None
        self.start()

    def start(self) -> None:
        assert SER2NET is not None
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen([SER2NET, "-n", "-d", "-c", str(self.config)],
                                         stdout=log, stderr=subprocess.STDOUT)
        wait_until(lambda: all(listening(p) for p in self.ports) or self.proc.poll() is not None,
                   "ser2net to listen")
        if self.proc.poll() is not None:
            raise AssertionError(f"ser2net exited: {self.log.read_text()[-2000:]}")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=WAIT)
        self.proc = None

    def __enter__(self) -> "Ser2net":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()


class Rfc2217Server:
    """pyserial's RFC 2217 PortManager over a pty device, one client at a time.

    ``refuse_baud``: a rate the serial side refuses (PortManager then answers
    with the rate it kept: the client must see the refusal)."""

    def __init__(self, device: str, refuse_baud: Optional[int] = None) -> None:
        import serial
        import serial.rfc2217

        class PtySerial(serial.Serial):      # type: ignore[misc]
            """A pty has no modem lines and takes any rate: refuse one on request."""

            def _update_rts_state(self) -> None:
                pass

            def _update_dtr_state(self) -> None:
                pass

            cts = dsr = ri = cd = property(lambda self: False)

            def _reconfigure_port(self, force_update: bool = False) -> None:
                if refuse_baud is not None and self._baudrate == refuse_baud:
                    raise ValueError(f"baud {refuse_baud} refused")
                super()._reconfigure_port(force_update)

        self._rfc = serial.rfc2217
        self.serial = PtySerial(device, 115200, timeout=0)
        self.port = free_port()
        self.url = f"rfc2217://127.0.0.1:{self.port}"
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", self.port))
        self.sock.listen(1)
        self.connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            r, _, _ = select.select([self.sock], [], [], 0.05)
            if not r:
                continue
            conn, _ = self.sock.accept()
            self.connections += 1
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            pm = self._rfc.PortManager(self.serial, _Writer(conn))
            try:
                self._relay(conn, pm)
            except OSError:
                pass              # the client went away (a reset): serve the next one
            finally:
                conn.close()

    def _relay(self, conn: socket.socket, pm: Any) -> None:
        fd = self.serial.fileno()
        while not self._stop.is_set():
            r, _, _ = select.select([conn, fd], [], [], 0.05)
            if conn in r:
                data = conn.recv(4096)
                if not data:
                    return
                out = b"".join(pm.filter(data))
                if out:
                    self.serial.write(out)
            if fd in r:
                data = os.read(fd, 4096)
                if data:
                    conn.sendall(b"".join(pm.escape(data)))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=WAIT)
        self.sock.close()
        self.serial.close()

    def __enter__(self) -> "Rfc2217Server":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class _Writer:
    """The ``connection`` PortManager writes its Telnet answers to."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn

    def write(self, data: bytes) -> None:
        self.conn.sendall(data)


class FaultProxy:
    """client <-> proxy <-> upstream, with faults set while it runs.

    ``delay``/``jitter`` (seconds) hold each chunk before forwarding it;
    ``split`` forwards every chunk one byte per send (TCP_NODELAY: one
    segment each); :meth:`reset` aborts every open connection with a RST.
    ``accepting=False`` refuses new clients (a server that is down)."""

    def __init__(self, upstream: int, seed: int = 1) -> None:
        self.upstream = upstream
        self.port = free_port()
        self.delay = 0.0
        self.jitter = 0.0
        self.split = False
        self.accepting = True
        self.connections = 0
        self.bytes: Dict[str, int] = {"up": 0, "down": 0}
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._socks: List[socket.socket] = []
        self._stop = threading.Event()
        self.listener: Optional[socket.socket] = None
        self._listen()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _listen(self) -> None:
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", self.port))
        s.listen(4)
        self.listener = s

    def url(self, scheme: str = "tcp") -> str:
        return f"{scheme}://127.0.0.1:{self.port}"

    def _accept(self) -> None:
        while not self._stop.is_set():
            lst = self.listener
            if lst is None:
                time.sleep(0.01)
                continue
            try:
                r, _, _ = select.select([lst], [], [], 0.05)
                if not r:
                    continue
                client, _ = lst.accept()
            except (OSError, ValueError):
                continue
            if not self.accepting:
                _abort(client)
                continue
            try:
                up = socket.create_connection(("127.0.0.1", self.upstream), timeout=WAIT)
            except OSError:
                _abort(client)
                continue
            for s in (client, up):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self.connections += 1
                self._socks += [client, up]
            for src, dst, key in ((client, up, "up"), (up, client, "down")):
                threading.Thread(target=self._pump, args=(src, dst, key), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, key: str) -> None:
        try:
            while not self._stop.is_set():
                data = src.recv(4096)
                if not data:
                    break
                hold = self.delay + (self._rng.uniform(0, self.jitter) if self.jitter else 0.0)
                if hold:
                    time.sleep(hold)   # the fault itself: a slow link, not synchronisation
                if self.split:
                    for b in data:
                        dst.sendall(bytes([b]))
                else:
                    dst.sendall(data)
                with self._lock:
                    self.bytes[key] += len(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def reset(self) -> None:
        """Abort every open connection (RST both ways)."""
        with self._lock:
            socks, self._socks = self._socks, []
        for s in socks:
            _abort(s)

    def close(self) -> None:
        self._stop.set()
        self.reset()
        self._thread.join(timeout=WAIT)
        if self.listener is not None:
            self.listener.close()

    def __enter__(self) -> "FaultProxy":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _abort(s: socket.socket) -> None:
    """Close with a RST (SO_LINGER 0), as a crashed server would."""
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
        # wake a pump thread blocked in recv (sends nothing), so the close
        # below really releases the socket and the RST goes out now
        s.shutdown(socket.SHUT_RD)
    except OSError:
        pass
    s.close()
