"""Faults by name, switched at run time (docs/sim.md, "Faults").

A :class:`FaultTable` holds the active faults of a sim. A responder asks :meth:`FaultTable.draw`
once per transaction (a request addressed to one of its nodes) which faults apply now: the
table is read at that moment, so an added or removed fault takes effect on the next
transaction. Each fault has a kind, a bus (or every bus), a node (or ``all``), a probability
drawn from its own seeded generator, parameters (``ms`` of ``late_reply`` and ``split``,
``rate`` of ``bit_errors`` and ``byte_drops``, ``word`` of ``error_reply``) and an optional
schedule (``at``/``for``/``every``, seconds of the wall clock from the moment it was added).
Every change is logged and counted; every application is counted per fault and per kind.
A schedule's edges are changes too: a thread of the table wakes at each one, logs it, drops a
fault whose ``for`` has run out, and tells the listeners (FAP slaves are opened and closed
there, not per transaction).
"""
from __future__ import annotations

import logging
import math
import random
import threading
import time
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
    "hung": "once drawn, the node answers nothing until the fault is removed (reset)",
    "split": "the reply is sent in two pieces, ms milliseconds apart",
    "bit_errors": "each reply (or, direction request, request) byte has one bit flipped with probability rate",
    "byte_drops": "each reply (or, direction request, request) byte is left out with probability rate",
    "error_reply": "the protocol's error answer: the node reports the error word (G485)",
}

#: kinds that replace or suppress the reply (one applies; late_reply combines with them)
_EXCLUSIVE = ("off", "hung", "no_reply", "garbage", "truncated", "wrong_address", "bad_crc",
              "error_reply", "bit_errors", "byte_drops", "split")

#: what the shared responder does to any request/reply protocol (a plug-in's ``FAULTS``
#: starts from it; ``error_reply`` needs the plug-in's own ``error_reply(node, word)``)
REPLY_KINDS: Tuple[str, ...] = ("off", "no_reply", "late_reply", "bad_crc", "wrong_address", "garbage",
                                "truncated", "hung", "split", "bit_errors", "byte_drops")

#: the parameter each kind needs, its default and its bounds
PARAMS: Dict[str, Tuple[str, float, float, float]] = {
    "late_reply": ("ms", 0.0, 0.0, 60000.0),
    "split": ("ms", 5.0, 0.0, 60000.0),
    "bit_errors": ("rate", 0.05, 0.0, 1.0),
    "byte_drops": ("rate", 0.05, 0.0, 1.0),
    "error_reply": ("word", 1.0, 1.0, 65535.0),
}

#: which way a fault acts: on what the node sends (its reply) or on what it hears (the
#: master's request: a damaged request fails the node's check, so it is not executed)
DIRECTIONS = ("reply", "request")
#: the kinds that act either way (the others are the node's own behaviour: replies only)
BOTH_WAYS = ("bit_errors", "byte_drops")

#: the longest schedule time (seconds): a day is plenty for a test bench
MAX_SCHEDULE_S = 86400.0


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
    rate: float = 0.0
    word: int = 0
    at: float = 0.0
    duration: Optional[float] = None      # ``for``: seconds active (each period with every)
    every: Optional[float] = None
    t0: float = 0.0                       # when it was added (time.monotonic)
    direction: str = "reply"              # DIRECTIONS
    hung: set = field(default_factory=set, repr=False)   # (bus, node) latched by ``hung``

    def matches(self, bus: str, node: int) -> bool:
        return (self.bus is None or self.bus == bus) and (self.node == "all" or self.node == node)

    @property
    def scheduled(self) -> bool:
        return self.at > 0 or self.duration is not None

    def active(self, t: float) -> bool:
        """In force at monotonic time ``t`` (its schedule; an unscheduled fault always is)."""
        rel = t - self.t0 - self.at
        if rel < 0:
            return False
        if self.every is not None and self.duration is not None:
            return math.fmod(rel, self.every) < self.duration
        return self.duration is None or rel < self.duration

    def expired(self, t: float) -> bool:
        return self.every is None and self.duration is not None and t - self.t0 - self.at >= self.duration

    def next_edge(self, t: float) -> Optional[float]:
        """The monotonic time of its next switch on or off after ``t`` (None: no more)."""
        if not self.scheduled:
            return None
        start = self.t0 + self.at
        if t < start:
            return start
        if self.duration is None:
            return None
        if self.every is None:
            return start + self.duration if t < start + self.duration else None
        k = math.floor((t - start) / self.every)
        on = start + k * self.every
        return on + self.duration if t < on + self.duration else on + self.every

    def public(self, t: Optional[float] = None) -> Dict[str, Any]:
        d: Dict[str, Any] = {"id": self.id, "kind": self.kind, "bus": self.bus, "node": self.node,
                             "probability": self.probability, "applied": self.applied}
        if self.kind in ("late_reply", "split"):
            d["ms"] = self.ms
        if self.kind in ("bit_errors", "byte_drops"):
            d["rate"] = self.rate
            d["direction"] = self.direction
        if self.kind == "error_reply":
            d["word"] = self.word
        if self.kind == "hung":
            d["hung_nodes"] = sorted(f"{b}:{n}" for b, n in self.hung)
        if self.scheduled:
            d["at"] = self.at
            if self.duration is not None:
                d["for"] = self.duration
            if self.every is not None:
                d["every"] = self.every
            d["active"] = self.active(time.monotonic() if t is None else t)
        return d


def _number(value: Any, what: str, lo: float, hi: float, *, lo_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not (lo < value if lo_open else lo <= value) or not value <= hi:
        raise FaultError(f"{what} must be {'more than ' if lo_open else ''}{lo:g}..{hi:g}, not {value!r}")
    return float(value)


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
        self.now = time.monotonic       # the schedules' clock (tests may replace it)
        self._wake = threading.Condition(self._lock)
        self._scheduler: Optional[threading.Thread] = None
        self._closed = False

    def add(self, kind: str, *, bus: Optional[str] = None, node: Union[int, str] = "all",
            probability: float = 1.0, ms: Optional[float] = None, seed: Optional[int] = None,
            rate: Optional[float] = None, word: Optional[int] = None, at: Optional[float] = None,
            duration: Optional[float] = None, every: Optional[float] = None,
            direction: str = "reply",
            allowed: Optional[Dict[str, Tuple[str, ...]]] = None) -> Fault:
        """Add a fault; ``allowed`` maps bus name -> the kinds its protocol implements.

        ``at`` (seconds from now, default 0), ``duration`` (the config's ``for``: seconds in
        force) and ``every`` (a period: in force ``duration`` seconds of each) schedule it.
        ``direction`` "request" (bit_errors, byte_drops only) damages what the node hears."""
        if kind not in KINDS:
            raise FaultError(f"unknown fault kind {kind!r} (kinds: {', '.join(KINDS)})")
        if direction not in DIRECTIONS:
            raise FaultError(f"direction must be one of {', '.join(DIRECTIONS)}, not {direction!r}")
        if direction == "request" and kind not in BOTH_WAYS:
            raise FaultError(f"{kind} acts on replies only (direction request: {', '.join(BOTH_WAYS)})")
        if isinstance(probability, bool) or not isinstance(probability, (int, float)) \
                or not 0.0 <= probability <= 1.0:
            raise FaultError(f"probability must be 0..1, not {probability!r}")
        given = {"ms": ms, "rate": rate, "word": word}
        for name, value in given.items():
            if value is not None and PARAMS.get(kind, ("",))[0] != name:
                raise FaultError(f"{name} is not a parameter of {kind}"
                                 + (f" (its parameter: {PARAMS[kind][0]})" if kind in PARAMS else ""))
        param = 0.0
        if kind in PARAMS:
            name, default, lo, hi = PARAMS[kind]
            value = given[name]
            param = default if value is None else _number(value, name, lo, hi)
            if name == "word" and param != int(param):
                raise FaultError(f"word must be a whole number 1..65535, not {value!r}")
        at_s = 0.0 if at is None else _number(at, "at", 0.0, MAX_SCHEDULE_S)
        dur = None if duration is None else _number(duration, "for", 0.0, MAX_SCHEDULE_S, lo_open=True)
        per = None if every is None else _number(every, "every", 0.0, MAX_SCHEDULE_S, lo_open=True)
        if per is not None and (dur is None or dur >= per):
            raise FaultError("every needs for, shorter than every (in force 'for' seconds of each 'every')")
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
            f = Fault(fid, kind, bus, node, float(probability), param if kind in ("late_reply", "split") else 0.0,
                      s, rng=random.Random(s), rate=param if kind in ("bit_errors", "byte_drops") else 0.0,
                      word=int(param) if kind == "error_reply" else 0, at=at_s, duration=dur, every=per,
                      t0=self.now(), direction=direction)
            self._faults.append(f)
            self._changed({"event": "add", **f.public(f.t0)})
            if f.scheduled:
                self._arm()
        log.warning("fault %d added: %s on bus %s node %s (p=%g%s%s%s)", fid, kind, bus or "*", node,
                    probability, f", {PARAMS[kind][0]} {param:g}" if kind in PARAMS else "",
                    ", on requests" if direction == "request" else "", _schedule_text(f))
        self._notify()
        return f

    # -- schedules ------------------------------------------------------------------------
    def _arm(self) -> None:
        """(lock held) Start the schedule thread, or wake it to look at a new edge."""
        if self._scheduler is None and not self._closed:
            self._scheduler = threading.Thread(target=self._run_schedule, name="fap-sim faults", daemon=True)
            self._scheduler.start()
        self._wake.notify_all()

    def _run_schedule(self) -> None:
        with self._lock:
            while not self._closed:
                t = self.now()
                for f in [f for f in self._faults if f.expired(t)]:
                    self._faults.remove(f)
                    self._changed({"event": "expire", **f.public(t)})
                    log.warning("fault %d ended (its 'for' ran out): %s, applied %d times", f.id, f.kind, f.applied)
                edges = [e for e in (f.next_edge(t) for f in self._faults) if e is not None]
                nxt = min(edges) if edges else None
                if nxt is not None and nxt <= t:
                    nxt = t + 0.001
                self._wake.wait(None if nxt is None else nxt - t)
                if self._closed:
                    return
                t2 = self.now()
                if nxt is not None and t2 >= nxt:
                    for f in self._faults:
                        if f.scheduled and f.active(t2) != f.active(t):
                            state = "on" if f.active(t2) else "off"
                            self._changed({"event": "switch", "state": state, **f.public(t2)})
                            log.warning("fault %d switched %s by its schedule: %s", f.id, state, f.kind)
                    self._lock.release()
                    try:
                        self._notify()
                    finally:
                        self._lock.acquire()

    def close(self) -> None:
        """Stop the schedule thread (the sim is closing)."""
        with self._lock:
            self._closed = True
            self._wake.notify_all()
        if self._scheduler is not None and self._scheduler is not threading.current_thread():
            self._scheduler.join(2.0)

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
            self._wake.notify_all()
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
            t = self.now()
            return [f.public(t) for f in self._faults]

    def is_off(self, bus: str, node: int) -> bool:
        """True when an ``off`` fault (probability 1) holds ``node`` now (FAP nodes)."""
        with self._lock:
            t = self.now()
            return any(f.kind == "off" and f.probability >= 1.0 and f.matches(bus, node) and f.active(t)
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
            t = self.now()
            for f in sorted((f for f in self._faults if f.matches(bus, node) and f.active(t)),
                            key=lambda f: (_EXCLUSIVE.index(f.kind) if f.kind in _EXCLUSIVE else 99, f.id)):
                if f.kind == "hung" and (bus, node) in f.hung:
                    main = main or f      # latched: no draw until the fault is removed
                elif f.kind == "late_reply":
                    if late is None and (f.probability >= 1.0 or f.rng.random() < f.probability):
                        late = f
                elif main is None and (f.probability >= 1.0 or f.rng.random() < f.probability):
                    main = f
                    if f.kind == "hung" and (bus, node) not in f.hung:
                        f.hung.add((bus, node))
                        self._changed({"event": "hung", "bus": bus, "node": node, "id": f.id})
                        log.warning("fault %d: bus %s node %d hung until the fault is removed", f.id, bus, node)
            if main is not None and main.kind in ("off", "no_reply", "hung"):
                late = None     # nothing is sent: nothing is late
            for hit in (main, late):
                if hit is not None:
                    hit.applied += 1
                    self.applied_by_kind[hit.kind] += 1
            return main, late


#: the keys a fault takes in a config table or a control request, beside ``kind``
FAULT_KEYS = ("bus", "node", "probability", "ms", "rate", "word", "seed", "at", "for", "every",
              "direction")


def fault_keywords(entry: Dict[str, Any]) -> Dict[str, Any]:
    """:meth:`FaultTable.add`'s keywords from a config table or control request (``for`` is a
    Python keyword: it is ``duration`` there)."""
    return {("duration" if k == "for" else k): entry[k] for k in FAULT_KEYS if k in entry}


def _schedule_text(f: Fault) -> str:
    if not f.scheduled:
        return ""
    out = f", at +{f.at:g} s" if f.at else ""
    if f.duration is not None:
        out += f", for {f.duration:g} s"
    if f.every is not None:
        out += f", every {f.every:g} s"
    return out
