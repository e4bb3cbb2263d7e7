"""Bus statistics: frames and errors by kind per node, bytes, utilisation,
reply times (end of a request to the start of its answer) per node."""
from __future__ import annotations

import random
from collections import defaultdict
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Dict, List, Mapping, Optional

from .._stats import Counters
from .._validate import U32, check_int, check_seconds
from ..errors import InvalidTypeError
from .core import Record
from .decoders import plugin


def _plural(n: int, word: str) -> str:
    """``1 frame``, ``2 frames`` (a report's wording, not API)."""
    return f"{n} {word if n == 1 else word + 's'}"


def _percentile(sorted_values: List[float], q: float) -> float:
    """Nearest-rank percentile of an ascending list."""
    k = max(0, min(len(sorted_values) - 1, int(round(q / 100.0 * len(sorted_values) + 0.5)) - 1))
    return sorted_values[k]


#: reply times kept per node for the percentiles: beyond, a uniform sample
#: (reservoir) of this many, so a long live run stays bounded in memory
REPLY_SAMPLES = 65536


class NodeStats:
    __slots__ = ("frames", "errors", "replies", "n_replies", "reply_max", "_rng")

    def __init__(self) -> None:
        self.frames = 0
        self.errors: Dict[str, int] = defaultdict(int)
        self.replies: List[float] = []    # all reply times, or a sample of REPLY_SAMPLES
        self.n_replies = 0
        self.reply_max = 0.0
        self._rng = random.Random(0)      # deterministic: the same input, the same summary

    def add_reply(self, seconds: float) -> None:
        seconds = check_seconds(seconds, "seconds")   # a NaN would poison max and percentiles
        self.n_replies += 1
        self.reply_max = max(self.reply_max, seconds)
        if len(self.replies) < REPLY_SAMPLES:
            self.replies.append(seconds)
            return
        k = self._rng.randrange(self.n_replies)
        if k < REPLY_SAMPLES:
            self.replies[k] = seconds


class Stats:
    """Accumulates records; :meth:`summary` gives the footer's numbers."""

    def __init__(self, baud: int = 0) -> None:
        """``baud``: the line rate, 0..2**32-1 (0 unknown: no utilisation)."""
        self.baud = check_int(baud, "baud", 0, U32)
        self.nodes: Dict[str, NodeStats] = defaultdict(NodeStats)
        self.frames = 0
        self.errors: Dict[str, int] = defaultdict(int)
        self.frame_bytes = 0
        self.bytes = 0
        self.t_first: Optional[float] = None
        self.t_last: Optional[float] = None
        # (node, key, t_end, port, raw) of the last request
        self._pending: Optional[tuple] = None

    def _node_and_role(self, rec: Record) -> tuple:
        """(node, 'req' | 'ans' | None, pairing key) of a good frame, from its
        protocol's plug-in (node None: not a frame)."""
        pend = self._pending
        return plugin(rec.protocol).pair(rec.event, pend[1] if pend else None)

    def add(self, rec: Record) -> None:
        """Count one record (InvalidTypeError for anything but a :class:`Record`)."""
        if not isinstance(rec, Record):
            raise InvalidTypeError(f"rec must be a Record, not {type(rec).__name__}")
        if rec.t is not None:
            if self.t_first is None:
                self.t_first = rec.t
            self.t_last = rec.t_end if rec.t_end is not None else rec.t
        if not rec.ok:
            reason = rec.error or "?"
            self.errors[reason] += 1
            self.nodes["?"].errors[reason] += 1
            return
        node, role, key = self._node_and_role(rec)
        if node is None:
            return                        # e.g. a wake-up preamble: neither a frame nor an error
        self.frames += 1
        self.frame_bytes += len(rec.raw)
        ns = self.nodes[str(node)]
        ns.frames += 1
        if role == "ans" and self._repeats_request(rec):
            role = "req"                  # a retry of the pending request, not its answer
        if role == "req":
            self._pending = (node, key, rec.t_end, rec.port, bytes(rec.raw))
        elif role == "ans":
            pend = self._pending
            if pend and (key is None or pend[1] == key) and pend[2] is not None \
                    and rec.t is not None:
                ns.add_reply(max(0.0, rec.t - pend[2]))
            self._pending = None

    def _repeats_request(self, rec: Record) -> bool:
        """In a protocol whose frames carry no direction (its plug-in's
        ``DIRECTIONLESS``: exec async, whose answer repeats the request's node
        and sequence number), a frame the plug-in calls an answer is still a
        request when it comes from the pending request's sender (captures
        name the port) or, where the sender is unknown (a live port), repeats
        its bytes exactly: a master's retry re-sends the same node, sequence
        number and data. Other protocols' frames say their direction. An echoing exec
        node's reply is byte-identical to its request: on a live port it is
        counted as a frame of the node but not timed (docs/monitor.md)."""
        pend = self._pending
        if pend is None or not getattr(plugin(rec.protocol), "DIRECTIONLESS", False):
            return False          # the frame's direction (its kind, a flag, the source) decides
        if rec.port is not None and pend[3] is not None:
            return rec.port == pend[3]
        return bytes(rec.raw) == pend[4]

    def utilisation(self) -> Optional[float]:
        """Share of the time the wire carried bytes (10 bits each), or None if unknown."""
        if not self.baud or self.t_first is None or self.t_last is None:
            return None
        span = self.t_last - self.t_first
        if span <= 0:
            return None
        return min(1.0, self.bytes * 10.0 / self.baud / span)

    def summary(self) -> Dict[str, Any]:
        nodes = {}
        for name in sorted(self.nodes, key=lambda k: (k == "?", int(k) if k.isdigit() else 0)):
            ns = self.nodes[name]
            r = sorted(ns.replies)
            nodes[name] = {
                "frames": ns.frames, "errors": dict(ns.errors),
                "replies": ns.n_replies,
                "reply_p50_ms": round(_percentile(r, 50) * 1e3, 3) if r else None,
                "reply_p99_ms": round(_percentile(r, 99) * 1e3, 3) if r else None,
                "reply_max_ms": round(ns.reply_max * 1e3, 3) if r else None,
            }
        util = self.utilisation()
        return {"frames": self.frames, "errors": dict(self.errors), "bytes": self.bytes,
                "frame_bytes": self.frame_bytes,
                "utilisation": None if util is None else round(util, 4), "nodes": nodes}

    @property
    def snapshot(self) -> "StatsSnapshot":
        """The numbers of :meth:`summary` so far, frozen (the package's stats contract)."""
        s = self.summary()
        return StatsSnapshot(s["frames"], s["errors"], s["bytes"], s["frame_bytes"],
                             s["utilisation"], s["nodes"])

    def footer(self) -> str:
        s = self.summary()
        errs = ", ".join(f"{k} {v}" for k, v in sorted(s["errors"].items())) or "none"
        util = "unknown" if s["utilisation"] is None else f"{s['utilisation'] * 100:.1f} %"
        lines = [f"-- {_plural(s['frames'], 'frame')}, errors: {errs}; {_plural(s['bytes'], 'byte')}; "
                 f"bus utilisation {util}"]
        for name, n in s["nodes"].items():
            e = ", ".join(f"{k} {v}" for k, v in sorted(n["errors"].items())) or "no errors"
            reply = "" if not n["replies"] else (
                f"; reply ms p50 {n['reply_p50_ms']} p99 {n['reply_p99_ms']} "
                f"max {n['reply_max_ms']} ({n['replies']})")
            label = "unattributed" if name == "?" else f"node {name}"
            lines.append(f"   {label}: {_plural(n['frames'], 'frame')}, {e}{reply}")
        return "\n".join(lines)


@dataclass(frozen=True)
class StatsSnapshot(Counters):
    """:meth:`Stats.summary` frozen: what ``Session.stats`` returns. Bad values raise
    InvalidTypeError / InvalidValueError; the mappings are read-only copies."""

    frames: int
    errors: Mapping[str, int]
    bytes: int
    frame_bytes: int
    utilisation: Optional[float]
    nodes: Mapping[str, Mapping[str, Any]]

    def __post_init__(self) -> None:
        for name in ("frames", "bytes", "frame_bytes"):
            check_int(getattr(self, name), name, 0, 2**63)
        if self.utilisation is not None:
            check_seconds(self.utilisation, "utilisation", hi=1.0)   # a share: 0..1
        for name in ("errors", "nodes"):
            value = getattr(self, name)
            if not isinstance(value, Mapping):
                raise InvalidTypeError(f"{name} must be a mapping, not {type(value).__name__}")
            frozen = {k: MappingProxyType(dict(v)) if isinstance(v, Mapping) else v
                      for k, v in value.items()}
            object.__setattr__(self, name, MappingProxyType(frozen))


__all__ = ["Stats", "StatsSnapshot"]
