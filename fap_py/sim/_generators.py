"""Value generators and clocks of ``fap sim``.

A generator is made from its config table (``{kind = "sine", period = 10}``) by :func:`make`
and read with ``gen(t)``: ``t`` is the clock's time in seconds since the sim started. Time
comes from a clock object (``now() -> float``): :class:`WallClock`, :class:`FastClock`
(``speed`` simulated seconds per second) or any object with ``now()`` (tests pass a fake
clock and move it by hand: no sleeps).
"""
from __future__ import annotations

import importlib
import logging
import math
import random
import threading
import time
from typing import Any, Callable, Dict, Optional

from .._validate import check_seconds
from ..errors import InvalidValueError

log = logging.getLogger("fap_py.sim")

__all__ = ["WallClock", "FastClock", "ManualClock", "Generator", "make", "to_bytes"]


class WallClock:
    """Seconds since it was made, from ``time.monotonic``."""

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0


class FastClock(WallClock):
    """Simulated time running ``speed`` times the wall clock."""

    def __init__(self, speed: float = 10.0) -> None:
        super().__init__()
        self.speed = check_seconds(speed, "speed (simulated seconds per second)", lo=0.0,
                                   lo_open=True, hi=1e6)

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.speed


class ManualClock:
    """A clock that moves only when told (:meth:`advance`): for tests and replays."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = check_seconds(t, "clock time", hi=1e12)

    def now(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        """Move the clock ``dt`` seconds forward (0 or more, finite)."""
        self.t += check_seconds(dt, "dt", hi=1e12)


def resolve_hook(spec: str) -> Any:
    """Import ``module:function``; any failure (the module raising on import) is one
    InvalidValueError."""
    mod_name, _, fn_name = spec.partition(":")
    try:
        mod = importlib.import_module(mod_name)
    except BaseException as exc:   # a hostile module may raise anything, SystemExit too
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise InvalidValueError(f"hook {spec!r}: importing {mod_name!r} failed: "
                                f"{type(exc).__name__}: {exc}") from None
    fn = getattr(mod, fn_name, None)
    if not callable(fn):
        raise InvalidValueError(f"hook {spec!r}: {mod_name!r} has no function {fn_name!r}")
    return fn


class GeneratorError(InvalidValueError):
    """A generator that cannot give a value (a hook that raised, or returned no number)."""


class Generator:
    """One value source; call it with the clock's time."""

    def __init__(self, spec: Dict[str, Any], seed: int = 0) -> None:
        self.spec = dict(spec)
        self.kind: str = spec["kind"]
        self.reads = 0
        self._lock = threading.Lock()
        g = spec.get
        self._rng = random.Random(g("seed", seed))
        self._hook: Optional[Callable[..., Any]] = None
        self.state: Dict[str, Any] = {}   # a hook's own state, kept between calls
        if self.kind == "hook":
            self._hook = resolve_hook(spec["function"])
        self._last: float = float(g("start", 0))

    def __call__(self, t: float) -> float:
        with self._lock:
            n = self.reads
            self.reads += 1
            return self._value(t, n)

    def _value(self, t: float, n: int) -> float:
        g: Any = self.spec.get
        k = self.kind
        if k == "const":
            return float(g("value"))
        if k == "counter":
            every = float(g("every", 0))
            steps = n if every <= 0 else math.floor(t / every)
            v = float(g("start", 0)) + steps * float(g("step", 1))
            wrap = g("wrap")
            if wrap is not None and wrap != g("start", 0):
                start = float(g("start", 0))
                v = start + math.fmod(v - start, float(wrap) - start)
            return v
        if k == "ramp":
            lo, hi, period = float(g("low", 0)), float(g("high", 100)), float(g("period", 10))
            frac = 0.0 if period <= 0 else (t % period) / period
            return lo + (hi - lo) * frac
        if k == "sine":
            period = float(g("period", 10))
            x = 0.0 if period <= 0 else t / period
            return float(g("offset", 0)) + float(g("amplitude", 1)) * math.sin(
                2 * math.pi * (x + float(g("phase", 0))))
        if k == "square":
            lo, hi, period = float(g("low", 0)), float(g("high", 100)), float(g("period", 10))
            frac = 0.0 if period <= 0 else (t % period) / period
            return hi if frac < float(g("duty", 0.5)) else lo
        if k == "random":
            lo, hi = g("low", 0), g("high", 100)
            if g("integer", True):
                return float(self._rng.randint(int(math.ceil(lo)), int(math.floor(hi))))
            return self._rng.uniform(float(lo), float(hi))
        if k == "steps":
            values = g("values")
            every = float(g("every", 0))
            i = n if every <= 0 else math.floor(t / every)
            return float(values[int(i) % len(values)])
        if k == "hook":
            assert self._hook is not None
            try:
                v = self._hook(t, self.state)
            except Exception as exc:
                raise GeneratorError(f"hook {g('function')}: {type(exc).__name__}: {exc}") from None
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v:
                raise GeneratorError(f"hook {g('function')} returned {v!r}, not a number")
            return float(v)
        raise GeneratorError(f"unknown generator kind {k!r}")  # pragma: no cover - schema


def make(spec: Dict[str, Any], seed: int = 0) -> Generator:
    """A generator from its config table."""
    return Generator(spec, seed)


def to_bytes(value: float, size: int, byteorder: str = "big", signed: bool = False) -> bytes:
    """``value`` rounded and kept to ``size`` bytes (clamped to the type's range)."""
    v = int(round(value))
    if signed:
        lo, hi = -(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1
    else:
        lo, hi = 0, (1 << (8 * size)) - 1
    v = min(max(v, lo), hi)
    return v.to_bytes(size, byteorder, signed=signed)  # type: ignore[arg-type]
