"""``fap sim``: a whole site of simulated devices from one config file (docs/sim.md).

The protocol-free parts live here (config and schema, generators and clocks, the fault table,
the request/reply responder, the control socket); each protocol's part is its plug-in
``fap_py.sim.protocols.<name>``, found by name through the protocol table (the shape of
``fap_py.monitor.protocols`` and ``fap_py.soak``)::

    from fap_py.sim import Sim, load
    with Sim(load("site.toml")) as sim:
        print(sim.buses[0].master_port)       # open your master here
        sim.add_fault("no_reply", node=5)
        print(sim.status())
"""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any, Dict, List, Optional

from .._validate import check_baud, check_path, check_seconds
from ..errors import InvalidTypeError
from ._config import SimConfigError, check_config, load, loads
from ._faults import KINDS, FaultError, FaultTable, fault_keywords
from ._generators import FastClock, ManualClock, WallClock
from ._plugins import plugin, plugin_name
from ._replay import Replay, ReplayError

log = logging.getLogger("fap_py.sim")

#: the public API; every other module of fap_py.sim is private (a leading ``_``), and what a
#: plug-in imports is in :mod:`fap_py.sim.protocols`
__all__ = ["Sim", "SimBus", "SimConfigError", "FaultError", "ReplayError", "KINDS", "load", "loads",
           "plugin", "plugin_name", "WallClock", "FastClock", "ManualClock", "Replay"]


class _Ctx:
    """What a plug-in's ``start`` gets for one bus."""

    def __init__(self, name: str, baud: int, paths: List[str], nodes: List[tuple], faults: FaultTable,
                 clock: Any, seed: int, rs485: Any) -> None:
        self.name, self.baud, self.paths, self.nodes = name, baud, paths, nodes
        self.faults, self.clock, self.seed, self.rs485 = faults, clock, seed, rs485


@dataclass
class SimBus:
    """One running bus (a record :class:`Sim` makes, in ``Sim.buses``): its name, protocol,
    the port left for the user's master, its node addresses, its runner."""

    name: str
    protocol: str
    master_port: Optional[str]
    runner: Any = field(repr=False)
    vbus: Any = field(repr=False)
    addresses: List[int] = field(default_factory=list)

    def status(self) -> Dict[str, Any]:
        nodes = self.runner.status()
        error = getattr(self.runner, "error", None)
        return {"name": self.name, "protocol": self.protocol, "master_port": self.master_port,
                "nodes": [{"address": a, **nodes[a]} for a in sorted(nodes)],
                "requests": sum(n["requests"] for n in nodes.values()),
                "unmatched": getattr(self.runner, "unmatched", 0),
                "reopened": getattr(self.runner, "reopened", 0),
                "error": None if error is None else f"{type(error).__name__}: {error}"}


class Sim:
    """Every bus of a checked config (:func:`load`), started; a context manager.

    ``clock``: the generators' time (default from the config: the wall clock, or a fast
    clock); ``port``: the port of the one bus, instead of the config's (``--port``);
    ``rs485``: line options of a real port.
    """

    def __init__(self, config: Dict[str, Any], *, clock: Any = None, port: Optional[str] = None,
                 baud: Optional[int] = None, rs485: Any = None) -> None:
        self.buses: List[SimBus] = []
        config = check_config(config)
        if port is not None:
            port = check_path(port, "port")
        if baud is not None:
            baud = check_baud(baud)
        if clock is not None and not callable(getattr(clock, "now", None)):
            raise InvalidTypeError(f"clock must have a now() method (a WallClock, FastClock or "
                                   f"ManualClock), not {type(clock).__name__}")
        if rs485 is not None:
            from ..rs485 import RS485

            if not isinstance(rs485, RS485):
                raise InvalidTypeError(f"rs485 must be a fap_py.rs485.RS485, not {type(rs485).__name__}")
        simcfg = config.get("sim", {})
        self.seed = int(simcfg.get("seed", 0))
        if clock is None:
            clock = FastClock(simcfg.get("speed", 10.0)) if simcfg.get("clock") == "fast" else WallClock()
        self.clock = clock
        self.faults = FaultTable(self.seed)
        self.allowed: Dict[str, tuple] = {}
        buses = config["bus"]
        if port is not None and len(buses) != 1:
            raise SimConfigError("--port", None, f"--port replaces the port of the one bus; "
                                 f"this config has {len(buses)} buses")
        try:
            for b, bus in enumerate(buses):
                self.buses.append(self._start_bus(b, bus, port, baud, rs485))
            for f in config.get("fault", ()):
                self.faults.add(f["kind"], allowed=self.allowed, **fault_keywords(f))
        except BaseException:
            self.close()
            raise

    def _start_bus(self, b: int, bus: Dict[str, Any], port: Optional[str], baud: Optional[int],
                   rs485: Any) -> SimBus:
        from ._config import node_addresses

        proto = plugin(bus["protocol"])
        name = bus.get("name", f"bus{b}")
        line = baud or bus.get("baud") or _default_baud(bus["protocol"])
        nodes: List[tuple] = []
        for n, node in enumerate(bus["node"]):
            addrs, _ = node_addresses(node, proto, ("bus", b, "node", n))
            nodes.extend((a, node) for a in addrs)
        per_node = getattr(proto, "PORT_PER_NODE", False)
        vbus = None
        master: Optional[str] = None
        if port is not None or "port" in bus:
            paths = [port if port is not None else bus["port"]]
        else:
            from ..vbus import VirtualBus

            v = bus.get("virtual", {})
            n_ports = 1 + (len(nodes) if per_node else 1)
            vbus = VirtualBus(ports=max(2, n_ports), baud=v.get("baud", line) or None,
                              link_dir=v.get("link_dir"), capture=v.get("capture"), seed=self.seed)
            master, paths = vbus.paths[0], vbus.paths[1:]
        ctx = _Ctx(name, line, paths, nodes, self.faults, self.clock, self.seed + 7919 * b, rs485)
        try:
            runner = proto.start(bus, ctx) if hasattr(proto, "start") else _start_responder(proto, ctx)
        except BaseException:
            if vbus is not None:
                vbus.close()
            raise
        self.allowed[name] = tuple(proto.FAULTS)
        log.info("bus %s (%s): %d nodes, master port %s", name, bus["protocol"], len(nodes), master or "-")
        return SimBus(name, bus["protocol"], master, runner, vbus, [a for a, _ in nodes])

    def add_fault(self, kind: str, **kw: Any) -> Dict[str, Any]:
        """Add a fault (the kinds each bus's protocol implements); its public record."""
        if not isinstance(kind, str):
            raise InvalidTypeError(f"fault kind must be a str, not {type(kind).__name__}")
        if kind == "late_reply" and "ms" not in kw:
            raise FaultError("late_reply needs ms (the delay in milliseconds)")
        if "for" in kw:
            kw["duration"] = kw.pop("for")
        whole = [b.name for b in self.buses if getattr(plugin(b.protocol), "PORT_PER_NODE", False)
                 and kw.get("bus") == b.name]
        p = kw.get("probability", 1.0)
        if kind == "off" and whole and isinstance(p, (int, float)) and p < 1.0:
            raise FaultError(f"bus {whole[0]!r}: its nodes are switched off whole: 'off' takes probability 1")
        return self.faults.add(kind, allowed=self.allowed, **kw).public()

    def remove_fault(self, fid: Any) -> List[Dict[str, Any]]:
        """Remove fault ``fid`` (an id :meth:`add_fault` returned), or every fault with
        ``"all"``; the public records of the removed ones."""
        if fid != "all" and (isinstance(fid, bool) or not isinstance(fid, int)):
            raise FaultError(f"a fault id is an int or 'all', not {fid!r}")
        return [f.public() for f in self.faults.remove(fid)]

    def faults_list(self) -> List[Dict[str, Any]]:
        """The public records of the faults in force."""
        return self.faults.list()

    def wait_for(self, predicate: Any, timeout: float = 5.0) -> bool:
        """Wait until ``predicate(self.status())`` holds (checked whenever a responder has
        handled requests, and every 50 ms for FAP nodes); False at the timeout."""
        import time

        if not callable(predicate):
            raise InvalidTypeError(f"predicate must be callable, not {type(predicate).__name__}")
        timeout = check_seconds(timeout, "timeout")
        deadline = time.monotonic() + timeout
        conds = [b.runner.handled for b in self.buses if hasattr(b.runner, "handled")]
        while True:
            if predicate(self.status()):
                return True
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            if conds:
                with conds[0]:
                    conds[0].wait(min(left, 0.05))
            else:
                threading.Event().wait(min(left, 0.05))

    def status(self) -> Dict[str, Any]:
        buses = [b.status() for b in self.buses]
        return {"buses": buses, "requests": sum(b["requests"] for b in buses),
                "faults": self.faults.list(), "faults_applied": dict(self.faults.applied_by_kind),
                "fault_changes": self.faults.changes}

    def close(self) -> None:
        self.faults.close()
        for b in reversed(self.buses):
            try:
                b.runner.stop()
            finally:
                if b.vbus is not None:
                    b.vbus.close()
        self.buses = []

    def __enter__(self) -> "Sim":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _default_baud(protocol: str) -> int:
    from .. import _protocols

    return _protocols.get(protocol).default_baud


def _start_responder(proto: ModuleType, ctx: _Ctx) -> Any:
    from ..port import Port
    from ._responder import Responder

    # a plug-in may open more kinds of port than the port layer (G485: pyserial URLs)
    opener = getattr(proto, "open_port", None)
    port = opener(ctx.paths[0], ctx.baud, ctx.rs485) if opener else Port(ctx.paths[0], ctx.baud, ctx.rs485)
    try:
        nodes = {a: proto.make_node(a, cfg, ctx.seed + a) for a, cfg in ctx.nodes}
        return Responder(ctx.name, proto, port, nodes, ctx.faults, ctx.clock, ctx.seed).start()
    except BaseException:
        port.close()
        raise
