"""A TCP proxy the test controls, to put faults between two MQTT peers (issue 37).

``FaultProxy(target_port)`` listens on a free loopback port and forwards each
connection to ``127.0.0.1:target_port``. :meth:`FaultProxy.set` changes what
happens to the traffic, at once, for every connection:

``pass``       forward both ways
``delay``      forward, each chunk held ``delay`` seconds first
``drop``       a partition: bytes are read and thrown away both ways, sockets stay
               open (no FIN, no RST: the peers learn it only from their keepalives)
``half_open``  the side towards the target is closed; the client's side stays open
               and silent (it learns nothing until its keepalive runs out)
``reset``      every connection is reset (RST) and new ones are reset at accept

Every connection has two forwarding threads that poll the mode (0.05 s); the
counters (connections, bytes forwarded, bytes dropped, resets) say what the
fault did.
"""
from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from typing import Dict, List, Optional, Tuple

log = logging.getLogger(__name__)

MODES = ("pass", "delay", "drop", "half_open", "reset")
_TICK = 0.05


def _reset(sock: socket.socket) -> None:
    """Close ``sock`` with an RST (SO_LINGER 0), not a FIN."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    except OSError:
        pass
    sock.close()


class FaultProxy:
    """A threaded loopback TCP proxy with switchable faults (a context manager)."""

    def __init__(self, target_port: int, target_host: str = "127.0.0.1") -> None:
        self.target = (target_host, target_port)
        self.mode = "pass"
        self.delay = 0.0
        self.counters: Dict[str, int] = {"connections": 0, "forwarded": 0, "dropped": 0, "resets": 0,
                                         "refused": 0}
        self._lock = threading.Lock()
        self._pairs: List[Tuple[socket.socket, Optional[socket.socket]]] = []
        self._stop = threading.Event()
        self._listener = socket.socket()
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(64)
        self._listener.settimeout(_TICK)
        self.port = self._listener.getsockname()[1]
        self._threads: List[threading.Thread] = []
        self._accept = threading.Thread(target=self._accept_loop, name="fault-proxy-accept", daemon=True)

    def __enter__(self) -> "FaultProxy":
        self._accept.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def set(self, mode: str, delay: float = 0.0) -> None:
        """Switch every connection (and the next ones) to ``mode``."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
        with self._lock:
            self.mode, self.delay = mode, delay
            pairs = list(self._pairs)
            if mode in ("reset", "half_open"):
                self._pairs = [] if mode == "reset" else [(c, None) for c, _ in pairs]
        log.info("fault proxy :%d -> :%d: %s", self.port, self.target[1], mode)
        for client, upstream in pairs:
            if mode == "reset":
                self.counters["resets"] += 1
                _reset(client)
                if upstream is not None:
                    _reset(upstream)
            elif mode == "half_open" and upstream is not None:
                upstream.close()

    def close(self) -> None:
        self._stop.set()
        self._listener.close()
        with self._lock:
            pairs, self._pairs = self._pairs, []
        for client, upstream in pairs:
            for s in (client, upstream):
                if s is not None:
                    s.close()
        for t in [self._accept, *self._threads]:
            if t.is_alive():
                t.join(2.0)

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            with self._lock:
                mode = self.mode
            if mode == "reset":
                self.counters["refused"] += 1
                _reset(client)
                continue
            self.counters["connections"] += 1
            upstream: Optional[socket.socket] = None
            if mode != "half_open":
                try:
                    upstream = socket.create_connection(self.target, timeout=2.0)
                except OSError:   # the target is down: the client sees its connection closed
                    self.counters["refused"] += 1
                    client.close()
                    continue
            with self._lock:
                self._pairs.append((client, upstream))
            if upstream is None:   # half-open from the start: accepted, then silence
                continue
            for src, dst in ((client, upstream), (upstream, client)):
                t = threading.Thread(target=self._forward, args=(src, dst), daemon=True,
                                     name=f"fault-proxy-{self.port}")
                t.start()
                self._threads.append(t)

    def _forward(self, src: socket.socket, dst: socket.socket) -> None:
        src.settimeout(_TICK)
        while not self._stop.is_set():
            try:
                data = src.recv(65536)
            except socket.timeout:
                continue
            except OSError:
                break
            if not data:
                break
            with self._lock:
                mode, delay = self.mode, self.delay
            if mode in ("drop", "half_open"):
                self.counters["dropped"] += len(data)
                continue
            if mode == "delay" and delay > 0:
                self._stop.wait(delay)
            try:
                dst.sendall(data)
            except OSError:
                break
            self.counters["forwarded"] += len(data)
        with self._lock:
            mode = self.mode
        if mode not in ("drop", "half_open"):   # a close passes through (a partition hides it)
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass


def wait_until(pred, timeout: float, tick: float = 0.02) -> bool:   # type: ignore[no-untyped-def]
    """Bounded polling of ``pred`` (never a sleep as synchronisation)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(tick)
    return bool(pred())
