"""Helpers of the daemon tests: a `fap serve` process on a paced virtual bus, client
processes, raw protocol sockets. A uniquely named module (not conftest) so other
components' helpers cannot shadow it. Waits are bounded polls of a condition."""
from __future__ import annotations

import contextlib
import json
import os
import select
import socket
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterator, List, Optional

from fap_py.serve import status

WAIT_S = 10.0


@contextlib.contextmanager
def _serving(step: Callable[[], None]) -> Iterator[None]:
    """Call ``step`` (it returns within about 0.1 s) over and over in a thread, for the block."""
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            step()

    t = threading.Thread(target=run, daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join(5)


@contextlib.contextmanager
def mikroc_echo(path: str, address: int = 0x12, baud: int = 19200) -> Iterator[Any]:
    """A mikroC slave on ``path`` answering each request with its bytes reversed, in a
    thread, for the block (yields the slave)."""
    from fap_py import mikroc
    from fap_py.errors import FapTimeoutError
    from fap_py.rs485 import RS485, RS485Mode

    def echo() -> None:
        try:
            msg = slave.receive(timeout=0.1)
        except FapTimeoutError:
            return
        slave.send(msg.data[::-1])

    with mikroc.Slave(path, baud, address=address, rs485=RS485(mode=RS485Mode.NONE)) as slave, \
            _serving(echo):
        yield slave


@contextlib.contextmanager
def fap_echo(path: str, slave_id: int = 3, baud: int = 115200, **options: Any) -> Iterator[Any]:
    """A FAP slave on ``path`` sending back each message reversed, in a thread, for the
    block (yields the slave: its counters). ``options``: the Slave's (``byte_gap`` ...)."""
    from fap_py import Slave
    from fap_py.rs485 import RS485, RS485Mode

    def echo() -> None:
        for msg in slave.messages(0.1):
            slave.send(msg.data[::-1])

    with Slave(path, baud, id=slave_id, rs485=RS485(mode=RS485Mode.NONE), **options) as slave, \
            _serving(echo):
        yield slave


def fap_cmd(*args: str) -> List[str]:
    """argv of the installed command as a process (-I: not the source tree)."""
    return [sys.executable, "-I", "-m", "fap_py", *args]


@dataclass
class Served:
    """A running `fap serve`: its process, pid, client URL and socket path."""

    proc: subprocess.Popen
    url: str
    sock: str
    ready: Dict[str, Any]

    @property
    def pid(self) -> int:
        return int(self.ready["pid"])

    def status(self) -> Dict[str, Any]:
        return status(self.url)

    def wait_for(self, cond: Callable[[Dict[str, Any]], bool], timeout: float = WAIT_S) -> Dict[str, Any]:
        """Poll the daemon's status until ``cond`` holds (bounded)."""
        end = time.monotonic() + timeout
        st = self.status()
        while not cond(st):
            if time.monotonic() > end:
                raise AssertionError(f"condition never held: {json.dumps(st)[:2000]}")
            time.sleep(0.01)
            st = self.status()
        return st

    def stop(self) -> str:
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            out, err = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
        return err.decode(errors="replace")


def start_daemon(tmp: str, port: str, *extra: str, protocol: str = "exec",
                 env: Optional[Dict[str, str]] = None) -> Served:
    sock = os.path.join(tmp, "bus.sock")
    argv = fap_cmd("serve", "--protocol", protocol, "--port", port, "--rs485", "none",
                   "--listen", f"unix:{sock}", "--lock-dir", tmp, "--json", *extra)
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0,
                         env=dict(os.environ, **(env or {})))
    assert p.stdout is not None
    end = time.monotonic() + WAIT_S
    while time.monotonic() < end:
        r, _, _ = select.select([p.stdout], [], [], max(0.0, end - time.monotonic()))
        if not r:
            break
        line = p.stdout.readline()
        if not line:
            break
        obj = json.loads(line)
        if obj.get("event") == "ready":
            return Served(p, "fapd://" + sock, sock, obj)
    p.kill()
    out, err = p.communicate()
    raise AssertionError(f"fap serve never got ready: {out!r} {err!r}")


CLIENT = r"""
import asyncio, json, sys
from fap_py.execasync import Master
url, cid, n, mode = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
bad = ok = 0
def tag(i): return f"{cid}:{i}".encode()
if mode == "sync":
    with Master(url, timeout=0.3, retries=2) as m:
        for i in range(n):
            r = m.transact(5, tag(i))
            ok += r == tag(i); bad += r != tag(i)
else:
    async def main():
        global ok, bad
        async with Master(url, timeout=0.3, retries=2) as m:
            async def one(i):
                global ok, bad
                r = await m.atransact(5, tag(i))
                ok += r == tag(i); bad += r != tag(i)
            for k in range(0, n, 4):
                await asyncio.gather(*[one(i) for i in range(k, min(n, k + 4))])
    asyncio.run(main())
print(json.dumps({"ok": ok, "bad": bad}))
"""


def client_proc(url: str, cid: int, n: int, mode: str = "sync") -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-I", "-c", CLIENT, url, str(cid), str(n), mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def raw_connect(path: str) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(WAIT_S)
    s.connect(path)
    return s


def send_msg(s: socket.socket, obj: Dict[str, Any]) -> None:
    body = json.dumps(obj).encode()
    s.sendall(struct.pack(">I", len(body)) + body)


def recv_msg(s: socket.socket) -> Optional[Dict[str, Any]]:
    """The next message, None at end of stream."""
    head = _recv_exact(s, 4)
    if len(head) < 4:
        return None
    (n,) = struct.unpack(">I", head)
    body = _recv_exact(s, n)
    return json.loads(body) if len(body) == n else None


def _recv_exact(s: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        try:
            chunk = s.recv(n - len(out))
        except (ConnectionResetError, socket.timeout):
            return out
        if not chunk:
            return out
        out += chunk
    return out


def closed_by_peer(s: socket.socket, timeout: float = WAIT_S) -> bool:
    """Whether the daemon closes ``s`` within ``timeout`` (reads and drops anything it sends)."""
    s.settimeout(timeout)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            chunk = s.recv(65536)
        except ConnectionResetError:
            return True
        except socket.timeout:
            return False
        if not chunk:
            return True
    return False
