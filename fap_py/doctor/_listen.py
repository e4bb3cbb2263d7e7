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
import termios
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

from ..errors import FapError
from ..monitor.core import Monitor
from ..monitor.decoders import monitor_protocols
from ..monitor.stats import Stats
from ._finding import Finding

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
    _flush_input(path)
    end = time.monotonic() + seconds
    with LivePort(path, baud) as port:
        for chunk in port.chunks(lambda: None, None, lambda: time.monotonic() >= end):
            if chunk is not None:
                out.append((chunk.now_ns, bytes(chunk.data)))
    return out


def _flush_input(path: str) -> None:
    """Drop what the tty buffered before we listen (bytes kept while nobody read,
    with holes where the buffer overflowed): the report is about the bus now."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return          # LivePort's open says why
    try:
        termios.tcflush(fd, termios.TCIFLUSH)
    except termios.error:
        pass
    finally:
        os.close(fd)


def measured_baud(cap: Capture) -> Optional[Tuple[int, float]]:
    """(nearest standard baud, measured character time s) from the arrival times, or
    None: per read, the time since the previous read over its bytes; the bulk of
    those is one character time when the bytes come paced."""
    per_read = [(t1 - t0) / len(data) / 1e9
                for (t0, _), (t1, data) in zip(cap, cap[1:]) if data and t1 > t0]
    if len(per_read) < 8:
        return None
    # the gaps between frames (and a late read) are the long tail: drop what is far
    # above the lower quartile, the median of the rest is one character time
    q25 = statistics.quantiles(per_read, n=4)[0]
    char_s = statistics.median([v for v in per_read if v <= 3 * q25])
    if char_s <= 0:
        return None
    best = min(STANDARD_BAUDS, key=lambda b: abs(math.log(char_s * b / 10.0)))
    ratio = char_s * best / 10.0
    if not 1 / TIMING_TOLERANCE <= ratio <= TIMING_TOLERANCE:
        return None
    return best, char_s


#: an arrival this much later than the bytes before it could have come (beyond the
#: character times) starts a new burst; closer ones are the same burst, re-timed. A
#: USB adapter hands bytes on in chunks up to its latency timer (16 ms), and a loaded
#: machine delivers late by as much: neither is a gap on the wire
BURST_SLACK_NS = 20_000_000


def wire_times(cap: Capture, baud: int) -> Capture:
    """The capture with each read re-dated to when its last byte left the wire: within a
    burst (reads closer than the bytes' wire time plus :data:`BURST_SLACK_NS`) byte after
    byte at the character time, so a reader's scheduling jitter does not move the
    records' times; a later read starts a new burst at its arrival."""
    if not baud:
        return cap
    char_ns = 10e9 / baud
    out: Capture = []
    end = None
    for now_ns, data in cap:
        due = None if end is None else end + len(data) * char_ns
        if due is not None and now_ns <= due + BURST_SLACK_NS:
            end = due
        else:
            end = float(now_ns)
        out.append((int(end), data))
    return out


def decode(cap: Capture, protocol: str, baud: int) -> Dict[str, Any]:
    """The capture through ``protocol``'s monitor decoder: Stats' summary."""
    mon = Monitor(protocol, baud)
    stats = Stats(baud)
    char_s = 10.0 / baud if baud else 0.0
    cap = wire_times(cap, baud)
    t0 = cap[0][0] if cap else 0
    recs = []
    for now_ns, data in cap:
        t = max(0.0, (now_ns - t0) / 1e9 - len(data) * char_s)
        # no arrival clock for the decoders (now_ns 0): what the reader's scheduling or
        # the adapter's latency stretch is no inter-byte gap; frames are told apart by
        # their framing, and the times (reply times) come with t
        recs += mon.feed(data, t=t, char_s=char_s)
    recs += mon.finish()
    for rec in recs:
        stats.add(rec)
    s = stats.summary()
    # the listening began and ended at any moment: a cut frame at either end is not
    # the bus's fault, so the share counts the records between the first and the
    # last good frame
    good = [i for i, r in enumerate(recs) if r.ok]
    inner = recs[good[0]:good[-1] + 1] if good else recs
    ok = sum(1 for r in inner if r.ok)
    s["share"] = ok / len(inner) if inner else 0.0
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
                           "nodes": nodes, "reply_p50_ms": replies, "bytes": n_bytes,
                           "errors": s["errors"]})
