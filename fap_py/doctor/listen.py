"""``--listen SECONDS``: which protocol and baud the bus carries, by listening only.

The port is opened receive-only through the monitor's :class:`LivePort` (mode
``none``, exclusive, never a byte sent). On a real UART each standard baud gets
a share of the time (the line is set to it; a wrong rate reads as garbage); on a
pseudo-terminal (a virtual bus) the line rate is not a setting, so the baud is
measured from the bytes' arrival times (a paced bus delivers one byte per
character time, 10 bits). Every protocol's monitor decoder (the plug-ins of
:mod:`fap_py.monitor.decoders`, through :class:`~fap_py.monitor.core.Monitor`
and :class:`~fap_py.monitor.stats.Stats`) decodes what was heard; the protocol
with the most clean frames wins, and its share of clean frames, nodes and reply
times are reported.
"""
from __future__ import annotations

import math
import os
import statistics
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

from ..errors import FapError
from ..monitor.core import Monitor
from ..monitor.decoders import monitor_protocols
from ..monitor.stats import Stats
from .finding import Finding

#: the rates tried on a real UART, most common first
STANDARD_BAUDS: Tuple[int, ...] = (9600, 19200, 38400, 57600, 115200, 4800, 2400, 1200, 230400)
#: good frames a protocol needs to be named
MIN_FRAMES = 2
#: how far a measured character time may be from a standard rate's (ratio)
TIMING_TOLERANCE = 1.3

Capture = List[Tuple[int, bytes]]   # (CLOCK_MONOTONIC ns of arrival, bytes)


def is_pty(path: str) -> bool:
    try:
        return 136 <= os.major(os.stat(path).st_rdev) <= 143
    except OSError:
        return False


def capture(path: str, baud: int, seconds: float) -> Capture:
    """What the port delivers in ``seconds`` at ``baud`` (receive-only)."""
    from ..monitor.sources import LivePort

    out: Capture = []
    end = time.monotonic() + seconds
    with LivePort(path, baud) as port:
        for chunk in port.chunks(lambda: None, None, lambda: time.monotonic() >= end):
            if chunk is not None:
                out.append((chunk.now_ns, bytes(chunk.data)))
    return out


def measured_baud(cap: Capture) -> Optional[Tuple[int, float]]:
    """(nearest standard baud, measured character time s) from the arrival times, or
    None: per read, the time since the previous read over its bytes; the median
    of those is one character time when the bytes come paced."""
    per_byte = []
    for (t0, _), (t1, data) in zip(cap, cap[1:]):
        if data and t1 > t0:
            per_byte.extend([(t1 - t0) / len(data) / 1e9] * len(data))
    if len(per_byte) < 8:
        return None
    char_s = statistics.median(per_byte)
    if char_s <= 0:
        return None
    best = min(STANDARD_BAUDS, key=lambda b: abs(math.log(char_s * b / 10.0)))
    ratio = char_s * best / 10.0
    if not 1 / TIMING_TOLERANCE <= ratio <= TIMING_TOLERANCE:
        return None
    return best, char_s


def decode(cap: Capture, protocol: str, baud: int) -> Dict[str, Any]:
    """The capture through ``protocol``'s monitor decoder: Stats' summary."""
    mon = Monitor(protocol, baud)
    stats = Stats(baud)
    char_s = 10.0 / baud if baud else 0.0
    t0 = cap[0][0] if cap else 0
    for now_ns, data in cap:
        dl = mon.idle_deadline()
        if dl is not None and dl < now_ns:
            for rec in mon.idle(dl):
                stats.add(rec)
        t = max(0.0, (now_ns - t0) / 1e9 - len(data) * char_s)
        for rec in mon.feed(data, t=t, char_s=char_s, now_ns=now_ns):
            stats.add(rec)
    for rec in mon.finish():
        stats.add(rec)
    s = stats.summary()
    bad = sum(s["errors"].values())
    s["share"] = s["frames"] / (s["frames"] + bad) if s["frames"] + bad else 0.0
    return s


def identify(slots: Sequence[Tuple[int, Capture]]) -> Dict[str, Any]:
    """The best (protocol, baud) over the captures, each taken at its baud."""
    best: Dict[str, Any] = {"protocol": None, "frames": 0, "share": 0.0, "baud": None}
    tried = []
    for baud, cap in slots:
        for p in monitor_protocols():
            s = decode(cap, p, baud)
            tried.append((p, baud, s["frames"], s["share"]))
            if (s["frames"], s["share"]) > (best["frames"], best["share"]):
                best = {"protocol": p, "baud": baud, "frames": s["frames"],
                        "share": s["share"], "summary": s}
    best["tried"] = tried
    return best


def listen(path: str, seconds: float, pty: Optional[bool] = None) -> Finding:
    """Listen on ``path`` for ``seconds`` and name the bus (a ``listen.bus`` finding)."""
    pty = is_pty(path) if pty is None else pty
    try:
        if pty:
            cap = capture(path, 9600, seconds)
            timing = measured_baud(cap)
            baud = timing[0] if timing else 0
            slots = [(baud, cap)]
        else:
            share = seconds / len(STANDARD_BAUDS)
            slots = [(b, capture(path, b, share)) for b in STANDARD_BAUDS]
            timing = None
    except (FapError, OSError) as exc:
        return Finding("listen.bus", "error", f"cannot listen on {path}: {exc}",
                       [f"{path}: {type(exc).__name__}: {exc}"],
                       "see port.holder / perm.group; stop the program holding it", port=path)
    n_bytes = sum(len(d) for _, cap in slots for _, d in cap)
    ev = [f"{path}: {n_bytes} bytes in {seconds:g} s" +
          (" (a pseudo-terminal: baud from the arrival times)" if pty else
           f" ({len(slots)} rates tried: {', '.join(map(str, STANDARD_BAUDS))})")]
    if timing:
        ev.append(f"character time {timing[1] * 1e6:.1f} us -> {timing[0]} baud")
    elif pty:
        ev.append("arrival times not paced: baud unknown")
    if not n_bytes:
        return Finding("listen.bus", "warning", f"nothing heard on {path} in {seconds:g} s",
                       ev, "check the A/B wiring and the termination; that a master polls",
                       port=path, detail={"protocol": None, "baud": None, "bytes": 0})
    res = identify(slots)
    for p, b, frames, share in res["tried"]:
        if frames:
            ev.append(f"{p} at {b or '?'} baud: {frames} frames, {share:.0%} clean")
    if res["protocol"] is None or res["frames"] < MIN_FRAMES:
        return Finding("listen.bus", "warning",
                       f"traffic on {path} ({n_bytes} bytes) but no protocol decodes it at the "
                       "standard rates", ev, "another protocol, a non-standard rate, or swapped "
                       "A/B lines (try swapping them)", port=path,
                       detail={"protocol": None, "baud": None, "bytes": n_bytes})
    s = res["summary"]
    nodes = [n for n in s["nodes"] if n != "?"]
    replies = {n: v["reply_p50_ms"] for n, v in s["nodes"].items() if v.get("replies")}
    if replies:
        ev.append("reply p50 ms: " + ", ".join(f"node {n} {v}" for n, v in replies.items()))
    baud_txt = f"{res['baud']} baud" if res["baud"] else "unknown baud"
    return Finding("listen.bus", "ok" if res["share"] >= 0.9 else "warning",
                   f"{res['protocol']} at {baud_txt}: {res['frames']} frames, "
                   f"{res['share']:.0%} clean; nodes {', '.join(nodes) or 'none'}", ev,
                   f"fap monitor --port {path} --protocol {res['protocol']}"
                   + (f" --baud {res['baud']}" if res["baud"] else ""), port=path,
                   detail={"protocol": res["protocol"], "baud": res["baud"] or None,
                           "frames": res["frames"], "share": round(res["share"], 4),
                           "nodes": nodes, "reply_p50_ms": replies, "bytes": n_bytes})
