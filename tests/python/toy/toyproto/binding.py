"""The toy protocol's own room: codec, master and slave over fap_py.port.Port.

Frame: ``0x5A | node | len | data[len] | sum`` where ``sum`` is the low byte of the sum of
every byte before it. A master sends a request to ``node``; that slave answers with a frame
whose node byte is ``node | REPLY`` carrying the data reversed. It exists for tests only.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import List, Optional, Tuple

from fap_py.errors import FapTimeoutError, FrameError, InvalidValueError
from fap_py.port import Port
from fap_py.rs485 import DEFAULT_BAUD

START = 0x5A
REPLY = 0x80                     # node byte of a reply: the node | REPLY
MAX_DATA = 32
NODE_MIN = 1
NODE_MAX = 9
BROADCAST = None

__all__ = ["START", "REPLY", "MAX_DATA", "NODE_MIN", "NODE_MAX", "BROADCAST", "DEFAULT_BAUD", "encode", "Decoder",
           "Master", "Slave", "Stats"]


def encode(node: int, data: bytes, reply: bool = False) -> bytes:
    """One frame to ``node`` (a request) or from it (``reply``)."""
    if not NODE_MIN <= node <= NODE_MAX or len(data) > MAX_DATA:
        raise InvalidValueError(f"toy frame: node {node} / {len(data)} bytes out of range")
    body = bytes([START, node | (REPLY if reply else 0), len(data)]) + bytes(data)
    return body + bytes([sum(body) & 0xFF])


class Decoder:
    """Sans-I/O: bytes in, ``(node, data)`` frames out; bad bytes are counted, never raised."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.rejected = 0

    def feed(self, chunk: bytes) -> List[Tuple[int, bytes]]:
        self._buf += chunk
        out: List[Tuple[int, bytes]] = []
        while self._buf:
            if self._buf[0] != START:
                del self._buf[0]
                self.rejected += 1
                continue
            if len(self._buf) < 3:
                break
            n = self._buf[2]
            if n > MAX_DATA:
                del self._buf[0]
                self.rejected += 1
                continue
            if len(self._buf) < n + 4:
                break
            frame = bytes(self._buf[:n + 4])
            if sum(frame[:-1]) & 0xFF != frame[-1]:
                del self._buf[0]
                self.rejected += 1
                continue
            del self._buf[:n + 4]
            out.append((frame[1], frame[3:-1]))
        return out


@dataclass(frozen=True)
class Stats:
    """Counters of one toy node (the package's stats contract: a frozen dataclass)."""

    frames_tx: int = 0
    frames_rx: int = 0
    rejected: int = 0
    timeouts: int = 0


class _Node:
    def __init__(self, path: str, baudrate: int) -> None:
        self._port = Port(path, baudrate)
        self._dec = Decoder()
        self._tx = self._rx = self._to = 0

    @property
    def stats(self) -> Stats:
        return Stats(self._tx, self._rx, self._dec.rejected, self._to)

    def close(self) -> None:
        self._port.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Master(_Node):
    """Sends a request and waits for the reply of the same node."""

    def __init__(self, path: str, baudrate: int = DEFAULT_BAUD, timeout: float = 0.2) -> None:
        super().__init__(path, baudrate)
        self.timeout = timeout

    def request(self, node: int, data: bytes) -> bytes:
        frame = encode(node, data)
        self._port.flush_input()
        self._port.write(frame)
        self._tx += 1
        deadline = time.monotonic_ns() + int(self.timeout * 1e9)
        while True:
            chunk = self._port.read_until(64, deadline)
            if not chunk:
                self._to += 1
                raise FapTimeoutError(f"toy node {node}: no reply in {self.timeout} s")
            for got_node, payload in self._dec.feed(chunk):
                if got_node == node | REPLY:
                    self._rx += 1
                    return payload
                if got_node != node:   # (node: our own request read back, no echo suppression)
                    raise FrameError(f"toy: frame from node byte {got_node:#x}, expected {node | REPLY:#x}")


class Slave(_Node):
    """Answers requests to ``node`` with the data reversed, in a thread of its own."""

    def __init__(self, path: str, node: int, baudrate: int = DEFAULT_BAUD) -> None:
        super().__init__(path, baudrate)
        self.node = node
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def start(self) -> "Slave":
        self._thread = threading.Thread(target=self._run, name=f"toy-slave-{self.node}", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            chunk = self._port.read_until(64, time.monotonic_ns() + 50_000_000)
            for node, payload in self._dec.feed(chunk):
                if node == self.node:
                    self._rx += 1
                    self._port.write(encode(node, payload[::-1], reply=True))
                    self._tx += 1

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        super().close()
