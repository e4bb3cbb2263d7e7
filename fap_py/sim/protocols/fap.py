"""FAP slaves of ``fap sim``: the C engine's :class:`fap_py.fap.Slave`, one per port of the
bus (the FAP engine owns its port), sending periodic messages and answering messages.

The FAP engine runs the protocol itself (polls, ID cycles, acknowledgements), so the byte-level
faults of the request/reply protocols are not available here: a FAP node implements ``off``
(the slave is closed, and opened again when the fault is removed: the master sees it inactive,
then active again).
"""
from __future__ import annotations

import logging
import os
import select
import threading
from typing import Any, Dict, List, Optional

from ... import fap
from ...errors import ClosedError, FapError, QueueFullError
from .._generators import make, to_bytes
from .._schema import HEX, MAX_LIST, Path, Problem

log = logging.getLogger("fap_py.sim")

NAME = "fap"
ADDRESS_MIN, ADDRESS_MAX = 1, fap.MAX_ID
FAULTS = ("off",)
#: one port per slave
PORT_PER_NODE = True

NODE_PROPERTIES: Dict[str, Any] = {
    "answer": {"enum": ["echo", "none"], "description": "what the slave does with a message: "
               "echo it to its sender, or nothing (default)"},
    "periodic": {"type": "array", "maxItems": MAX_LIST, "items": {
        "type": "object", "additionalProperties": False, "required": ["every"],
        "properties": {
            "every": {"type": "number", "minimum": 0.001, "description": "seconds (clock time)"},
            "to": {"type": "integer", "minimum": 0, "maximum": 31, "description": "default 0 (the master)"},
            "data": HEX,
            "value": {"$ref": "#/$defs/generator", "description": "a generator (instead of data/initial)"},
            "size": {"type": "integer", "minimum": 1, "maximum": 8, "description": "value: bytes (default 2)"},
        }}, "description": "messages the slave sends by itself"},
}


def check_node(node: Dict[str, Any], where: Path) -> List[Problem]:
    out = []
    for i, p in enumerate(node.get("periodic", ())):
        if ("data" in p) == ("value" in p):
            out.append(Problem(where + ("periodic", i), "a periodic message has 'data' or 'value' (one)"))
        elif "data" in p and not bytes.fromhex(p["data"].replace(":", " ")):
            out.append(Problem(where + ("periodic", i, "data"), "a FAP message has 1..1024 bytes"))
    return out


class _Stats:
    def __init__(self) -> None:
        self.requests = 0     # messages received
        self.replies = 0      # messages sent (echoes and periodic)
        self.faults: Dict[str, int] = {}
        self.errors = 0


class _Node:
    def __init__(self, bus: str, address: int, path: str, baud: int, cfg: Dict[str, Any], ctx: Any) -> None:
        self.bus, self.address, self.path, self.baud = bus, address, path, baud
        self.echo = cfg.get("answer", "none") == "echo"
        self.ctx = ctx
        self.stats = _Stats()
        self.periodic = []
        for i, p in enumerate(cfg.get("periodic", ())):
            gen = make(p["value"], ctx.seed + address * 100 + i) if "value" in p else None
            data = bytes.fromhex(p["data"].replace(":", " ")) if "data" in p else b""
            self.periodic.append([float(p["every"]), p.get("to", 0), data, gen, p.get("size", 2), None])
        self.slave: Optional[fap.Slave] = None
        self._off = False
        self._open()

    def _open(self) -> None:
        self.slave = fap.Slave(self.path, self.baud, id=self.address)

    def _close(self) -> None:
        s, self.slave = self.slave, None
        if s is not None:
            s.close()

    def sync_off(self) -> None:
        """Open or close the slave as the fault table's ``off`` says now."""
        off = self.ctx.faults.is_off(self.bus, self.address)
        if off == self._off:
            return
        self._off = off
        if off:
            self.stats.faults["off"] = self.stats.faults.get("off", 0) + 1
            with self.ctx.faults._lock:
                self.ctx.faults.applied_by_kind["off"] += 1
                for f in self.ctx.faults._faults:
                    if f.kind == "off" and f.matches(self.bus, self.address):
                        f.applied += 1
                        break
            self._close()
            log.warning("%s node %d switched off", self.bus, self.address)
        else:
            self._open()
            log.warning("%s node %d switched on", self.bus, self.address)

    def periodic_step(self, t: float) -> float:
        """Send the periodic messages due at clock time ``t``; clock seconds to the next."""
        s = self.slave
        nxt = float("inf")
        for p in self.periodic:
            every, to, data, gen, size, due = p
            if due is None:
                p[5] = due = t
            if t >= due:
                p[5] = due + every if due + every > t else t + every
                if s is not None:
                    self._send(s, to_bytes(gen(t), size) if gen is not None else data, to)
            nxt = min(nxt, p[5] - t)
        return nxt

    def drain(self) -> None:
        """Take every queued message (echo it if asked) and event (not used: the master's view)."""
        s = self.slave
        if s is None:
            return
        try:
            while True:
                msg = s.recv_nowait()
                if msg is None:
                    break
                self.stats.requests += 1
                if self.echo:
                    self._send(s, msg.data, msg.source)
            for _ in s.events(timeout=0.0):
                pass
        except ClosedError:
            return

    def _send(self, s: fap.Slave, data: bytes, to: int) -> None:
        try:
            s.send(data, to=to)
            self.stats.replies += 1
        except (QueueFullError, FapError) as exc:
            self.stats.errors += 1
            log.debug("%s node %d: %s", self.bus, self.address, exc)


class Runner:
    """One thread for every slave of the bus: it waits in ``poll`` on the engines'
    notification fds (a message or event queued), a wake-up pipe (a fault changed, stop) and
    the next periodic message's time; an idle bus costs nothing but its C engines."""

    def __init__(self, nodes: List[_Node], faults: Any, clock: Any) -> None:
        self.nodes, self.faults, self.clock = nodes, faults, clock
        self._stop = threading.Event()
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        os.set_blocking(self._w, False)
        faults.listeners.append(self._wake)
        self.error: Optional[BaseException] = None
        self._thread = threading.Thread(target=self._loop, daemon=True, name="fap-sim fap")
        self._thread.start()

    def _wake(self) -> None:
        try:
            os.write(self._w, b"x")
        except OSError:   # full (a wake-up is pending anyway) or closed
            pass

    def _loop(self) -> None:
        speed = float(getattr(self.clock, "speed", 1.0))    # clock seconds per second
        try:
            while not self._stop.is_set():
                for n in self.nodes:
                    n.sync_off()
                t = self.clock.now()
                wait = min([1.0] + [n.periodic_step(t) / speed for n in self.nodes])
                poller = select.poll()
                poller.register(self._r, select.POLLIN)
                for n in self.nodes:
                    if n.slave is not None:
                        poller.register(n.slave.fileno(), select.POLLIN)
                ready = poller.poll(max(0.0, wait) * 1000.0)
                if any(fd == self._r for fd, _ in ready):
                    try:
                        os.read(self._r, 4096)
                    except OSError:
                        pass
                for n in self.nodes:
                    n.drain()
        except BaseException as exc:   # reported in status
            if not self._stop.is_set():
                self.error = exc
                log.error("FAP sim stopped: %s: %s", type(exc).__name__, exc)

    def stop(self) -> None:
        self._stop.set()
        self._wake()
        self._thread.join(5.0)
        try:
            self.faults.listeners.remove(self._wake)
        except ValueError:
            pass
        for n in self.nodes:
            n._close()
        os.close(self._r)
        os.close(self._w)

    def status(self) -> Dict[int, Dict[str, Any]]:
        return {n.address: {"requests": n.stats.requests, "replies": n.stats.replies,
                            "faults": dict(n.stats.faults), "errors": n.stats.errors,
                            "state": "off" if n._off else "on"} for n in self.nodes}


def start(bus: Dict[str, Any], ctx: Any) -> Runner:
    """One C slave per node on the bus's node ports (``ctx.paths``)."""
    nodes: List[_Node] = []
    try:
        for (address, cfg), path in zip(ctx.nodes, ctx.paths):
            nodes.append(_Node(ctx.name, address, path, ctx.baud, cfg, ctx))
    except BaseException:
        for n in nodes:
            n._close()
        raise
    return Runner(nodes, ctx.faults, ctx.clock)
