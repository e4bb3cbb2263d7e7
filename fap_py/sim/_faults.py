"""Faults by name, switched at run time (docs/sim.md, "Faults").

A :class:`FaultTable` holds the active faults of a sim. A responder asks :meth:`FaultTable.draw`
once per transaction (a request addressed to one of its nodes) which faults apply now: the
table is read at that moment, so an added or removed fault takes effect on the next
transaction. Each fault has a kind, a bus (or every bus), a node (or ``all``), a probability
drawn from its own seeded generator and parameters (``ms`` of ``late_reply``). Every change is
logged and counted; every application is counted per fault and per kind.
"""
from __future__ import annotations

import logging
import random
import threading
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple, Union

from ..errors import InvalidValueError

log = logging.getLogger("fap_py.sim")

#: every fault kind, and what it does to a transaction
KINDS: Dict[str, str] = {
    "off": "the node is switched off: it hears nothing and answers nothing",
    "no_reply": "the node takes the request (it is counted) but sends no reply",
    "late_reply": "the reply is sent ms milliseconds late",
    "bad_crc": "the reply's check (CRC/checksum) is wrong",
    "wrong_address": "the reply carries another node's address",
    "garbage": "random bytes instead of the reply",
    "truncated": "only the first half of the reply frame",
}

#: kinds that replace or suppress the reply (one applies; late_reply combines with them)
_EXCLUSIVE = ("off", "no_reply", "garbage", "truncated", "wrong_address", "bad_crc")


class FaultError(InvalidValueError):
    """A fault that cannot be added or removed (unknown kind, node, id)."""


@dataclass
class Fault:
    id: int
    kind: str
    bus: Optional[str] = None
    node: Union[int, str] = "all"
    probability: float = 1.0
    ms: float = 0.0
    seed: int = 0
    applied: int = 0
    rng: random.Random = field(default_factory=random.Random, repr=False)

    def matches(self, bus: str, node: int) -> bool:
        return (self.bus is None or self.bus == bus) and (self.node == "all" or self.node == node)

    def public(self) -> Dict[str, Any]:
        d: Dict[str, Any] = {"id": self.id, "kind": self.kind, "bus": self.bus, "node": self.node,
                             "probability": self.probability, "applied": self.applied}
        if self.kind == "late_reply":
            d["ms"] = self.ms
        return d


class FaultTable:
    """The active faults (thread-safe)."""

    def __init__(self, seed: int = 0) -> None:
        self._lock = threading.Lock()
        self._faults: List[Fault] = []
        self._next = 1
        self.seed = seed
        self.changes = 0
        self.applied_by_kind: Dict[str, int] = dict.fromkeys(KINDS, 0)
        self.events: List[Dict[str, Any]] = []   # the last changes (bounded)
        self.version = 0   # bumped on every change
        #: called (no arguments, lock not held) after every change: a runner that does not
        #: look at the table per transaction (FAP) wakes up and re-reads it
        self.listeners: List[Any] = []

    def add(self, kind: str, *, bus: Optional[str] = None, node: Union[int, str] = "all",
            probability: float = 1.0, ms: float = 0.0, seed: Optional[int] = None,
            allowed: Optional[Dict[str, Tuple[str, ...]]] = None) -> Fault:
        """Add a fault; ``allowed`` maps bus name -> the kinds its protocol implements."""
        if kind not in KINDS:
            raise FaultError(f"unknown fault kind {kind!r} (kinds: {', '.join(KINDS)})")
        if isinstance(probability, bool) or not isinstance(probability, (int, float)) \
                or not 0.0 <= probability <= 1.0:
            raise FaultError(f"probability must be 0..1, not {probability!r}")
        if isinstance(ms, bool) or not isinstance(ms, (int, float)) or not 0.0 <= ms <= 60000.0:
            raise FaultError(f"ms must be 0..60000, not {ms!r}")
        if node != "all" and (isinstance(node, bool) or not isinstance(node, int) or not 0 <= node <= 255):
            raise FaultError(f"node must be an address 0..255 or 'all', not {node!r}")
        if bus is not None and not isinstance(bus, str):
            raise FaultError(f"bus must be a bus name, not {bus!r}")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise FaultError(f"seed must be an integer, not {seed!r}")
        if allowed is not None:
            buses = [bus] if bus is not None else list(allowed)
            if bus is not None and bus not in allowed:
                raise FaultError(f"no bus is named {bus!r} (buses: {', '.join(allowed)})")
            if not any(kind in allowed[b] for b in buses):
                raise FaultError(f"fault kind {kind!r} is not implemented on "
                                 f"{'bus ' + repr(bus) if bus else 'any bus'} (its kinds: "
                                 f"{', '.join(sorted(set().union(*(allowed[b] for b in buses))))})")
        with self._lock:
            fid = self._next
            self._next += 1
            s = self.seed * 1_000_003 + fid if seed is None else seed
            f = Fault(fid, kind, bus, node, float(probability), float(ms), s, rng=random.Random(s))
            self._faults.append(f)
            self._changed({"event": "add", **f.public()})
        log.warning("fault %d added: %s on bus %s node %s (p=%g%s)", fid, kind, bus or "*", node,
                    probability, f", {ms:g} ms" if kind == "late_reply" else "")
        self._notify()
        return f

    def remove(self, fid: Union[int, str]) -> List[Fault]:
        """Remove fault ``fid`` (or every fault with ``"all"``); the removed ones."""
        with self._lock:
            if fid == "all":
                gone, self._faults = self._faults, []
            else:
                gone = [f for f in self._faults if f.id == fid]
                if not gone:
                    raise FaultError(f"no fault has id {fid!r} (ids: "
                                     f"{', '.join(str(f.id) for f in self._faults) or 'none'})")
                self._faults = [f for f in self._faults if f.id != fid]
            for f in gone:
                self._changed({"event": "remove", **f.public()})
        for f in gone:
            log.warning("fault %d removed: %s (applied %d times)", f.id, f.kind, f.applied)
        self._notify()
        return gone

    def _notify(self) -> None:
        for fn in list(self.listeners):
            fn()

    def _changed(self, event: Dict[str, Any]) -> None:
        self.changes += 1
        self.version += 1
        self.events.append(event)
        del self.events[:-100]

    def list(self) -> List[Dict[str, Any]]:
        with self._lock:
            return [f.public() for f in self._faults]

    def is_off(self, bus: str, node: int) -> bool:
        """True when an ``off`` fault (probability 1) holds ``node`` now (FAP nodes)."""
        with self._lock:
            return any(f.kind == "off" and f.probability >= 1.0 and f.matches(bus, node)
                       for f in self._faults)

    def draw(self, bus: str, node: int) -> Tuple[Optional[Fault], Optional[Fault]]:
        """For one transaction of ``node`` on ``bus``: (the fault that replaces or suppresses
        its reply, or None; a late_reply fault, or None), each drawn with its probability and
        counted when it applies."""
        with self._lock:
            if not self._faults:
                return None, None
            main: Optional[Fault] = None
            late: Optional[Fault] = None
            for f in sorted((f for f in self._faults if f.matches(bus, node)),
                            key=lambda f: (_EXCLUSIVE.index(f.kind) if f.kind in _EXCLUSIVE else 99, f.id)):
                if f.kind == "late_reply":
                    if late is None and (f.probability >= 1.0 or f.rng.random() < f.probability):
                        late = f
                elif main is None and (f.probability >= 1.0 or f.rng.random() < f.probability):
                    main = f
            if main is not None and main.kind in ("off", "no_reply"):
                late = None     # nothing is sent: nothing is late
            for hit in (main, late):
                if hit is not None:
                    hit.applied += 1
                    self.applied_by_kind[hit.kind] += 1
            return main, late
