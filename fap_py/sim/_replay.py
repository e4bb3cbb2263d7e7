"""``fap sim --replay CAPTURE``: a recorded bus turned into responders (docs/sim.md, "Replay").

The capture is the virtual bus's format (docs/vbus.md) or a pcap the monitor wrote (its link
type, docs/monitor.md: each packet names its protocol and sender port; the packets of the
replayed protocol are taken, and a pcap whose packets name no sender is refused, since
requests and replies cannot be told apart). The master's port is the sender of the first
record (or the one named). Its bytes are cut into frames by the protocol's own decoder
(the C codec table for exec async and mikroC, ``fap_py.g485.codec.Parser`` for G485); what the
other ports sent after a request, until the master's next frame, is that request's reply, and
its delay is the time from the end of the request on the wire to the start of the reply. Live,
every frame the master sends is looked up by its exact bytes: a recorded request gets its
recorded replies in turn (the last one again once they are used up) after the recorded delay;
a request never recorded is counted (``unmatched``) and logged, and gets no reply.
"""
from __future__ import annotations

import heapq
import logging
import threading
import time
from typing import Any, Dict, List, Optional, Tuple

from ..errors import ClosedError, FapError, InvalidValueError, PortError

log = logging.getLogger("fap_py.sim")

#: a recorded reply is sent at its deadline (the request's arrival plus the recorded delay),
#: kept by the serving loop itself, no thread per reply: its port read waits until
#: READ_EARLY_S before the next deadline (the port layer's poll counts whole milliseconds),
#: time.sleep (clock_nanosleep) until SPIN_S before it, then a spin on the monotonic clock
READ_EARLY_S = 0.002
SPIN_S = 0.0002
#: this responder's own part of a delay: the request's last byte to the read's return, and the
#: write to the reply's first byte on the line; the write is that much before the recorded
#: delay runs out (bench/sim.py measured 220 us on a loaded 2-core machine on a pty: the
#: signed median of replayed minus recorded delays without it, +2.6 character times at 115200)
TURNAROUND_S = 0.0002

def replay_protocols() -> List[str]:
    """The protocols a capture can be replayed for: those whose sim plug-in frames a raw
    stream (``raw_frames``: the request/reply protocols)."""
    from ._plugins import plugin, simulated

    return [n for n in simulated() if hasattr(plugin(n), "raw_frames")]


class ReplayError(InvalidValueError):
    """A capture that cannot be replayed (no master frames, an unknown protocol)."""


def _framer(protocol: str, baud: int) -> Any:
    """``feed(data) -> [(end offset or None, raw frame)]`` by the protocol's own decoder."""
    from ._plugins import plugin

    return plugin(protocol).raw_frames(baud)


class ReplayTable:
    """Recorded request bytes -> the replies and their delays (seconds), in recorded order."""

    def __init__(self) -> None:
        self.entries: Dict[bytes, List[Tuple[bytes, float]]] = {}
        self.requests = 0

    def add(self, request: bytes, reply: bytes, delay: float) -> None:
        self.entries.setdefault(request, []).append((reply, delay))
        self.requests += 1


def build_table(capture: Any, protocol: str, master_port: Optional[int] = None) -> ReplayTable:
    """Pair the master's frames of ``capture`` (a :class:`fap_py.vbus.Capture`) with the replies."""
    names = replay_protocols()
    if protocol not in names:
        raise ReplayError(f"replay is for {', '.join(names)}, not {protocol!r}")
    records = capture.records
    if not records:
        raise ReplayError("the capture holds no bytes")
    master = records[0].port if master_port is None else master_port
    baud = int(capture.header.get("baud", "0") or 0)
    char_us = 10e6 / baud if baud else 0.0
    framer = _framer(protocol, baud)
    table = ReplayTable()
    pending: Optional[Tuple[bytes, float]] = None     # (request, its end on the wire, us)
    reply = b""
    reply_start: Optional[float] = None
    consumed = 0          # bytes of the master's stream fed so far

    def close() -> None:
        if pending is not None:
            delay = 0.0 if reply_start is None else max(0.0, (reply_start - pending[1]) / 1e6)
            table.add(pending[0], reply, delay)

    for rec in records:
        if rec.port == master:
            start = consumed
            consumed += len(rec.data)
            for end, raw in framer.feed(rec.data):
                close()
                within = (end - start) if end is not None else len(rec.data)
                pending = (raw, rec.t_us + max(0, within) * char_us)
                reply, reply_start = b"", None
        elif pending is not None:
            if reply_start is None:
                reply_start = float(rec.t_us)
            reply += rec.data
    close()
    if not table.entries:
        raise ReplayError(f"no {protocol} frame from port {master} in the capture")
    return table


class ReplayResponder:
    """Answers the master's frames on ``port`` from a :class:`ReplayTable`."""

    def __init__(self, name: str, protocol: str, port: Any, table: ReplayTable) -> None:
        self.name, self.protocol, self.port, self.table = name, protocol, port, table
        self._framer = _framer(protocol, port.baudrate)
        self._next: Dict[bytes, int] = {}
        self.matched = 0
        self.unmatched = 0
        self.replies = 0
        self.handled = threading.Condition()
        self._stop = threading.Event()
        # replies waiting for their deadline: (monotonic s, order, reply), soonest first
        self._due: List[Tuple[float, int, bytes]] = []
        self._order = 0
        self.error: Optional[BaseException] = None
        self._thread = threading.Thread(target=self._serve, daemon=True, name=f"fap-sim replay {name}")
        self._thread.start()

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                self._send_due()
                # wake for the next reply's deadline (a little early: see READ_EARLY_S), or in 1 s
                wake = self._due[0][0] - READ_EARLY_S if self._due else time.monotonic() + 1.0
                try:
                    data = self.port.read(4096, deadline_ns=max(0, int(wake * 1e9)))
                except ClosedError:
                    return
                except PortError:
                    if self._stop.wait(0.05):
                        return
                    continue
                if not data:
                    continue
                arrived = time.monotonic()     # the delays count from the request's end
                for _, raw in self._framer.feed(data):
                    self._answer(raw, arrived)
                with self.handled:
                    self.handled.notify_all()
        except BaseException as exc:
            if not self._stop.is_set():
                self.error = exc
                log.error("replay %s stopped: %s", self.name, exc)

    def _answer(self, raw: bytes, arrived: float) -> None:
        entries = self.table.entries.get(raw)
        if entries is None:
            self.unmatched += 1
            log.warning("replay %s: request not in the capture: %s", self.name, raw.hex(" "))
            return
        self.matched += 1
        i = self._next.get(raw, 0)
        reply, delay = entries[min(i, len(entries) - 1)]
        self._next[raw] = i + 1
        if not reply:
            return
        deadline = arrived + delay - TURNAROUND_S
        if deadline <= time.monotonic():
            self._write(reply)
            return
        self._order += 1
        heapq.heappush(self._due, (deadline, self._order, reply))
        self._send_due()

    def _send_due(self) -> None:
        """Send every reply whose deadline is within READ_EARLY_S, each at its deadline."""
        due = self._due
        while due and due[0][0] - time.monotonic() <= READ_EARLY_S:
            deadline, _, reply = heapq.heappop(due)
            left = deadline - time.monotonic()
            if left > SPIN_S:
                time.sleep(left - SPIN_S)
            while time.monotonic() < deadline:
                pass    # the last SPIN_S: a sleep's wake-up comes tens of microseconds late
            self._write(reply)

    def _write(self, reply: bytes) -> None:
        if self._stop.is_set():
            return
        try:
            self.port.write(reply)
            self.replies += 1
        except FapError as exc:
            log.warning("replay %s: reply lost: %s", self.name, exc)

    def stop(self) -> None:
        self._stop.set()
        try:
            self.port.close()
        except FapError:  # pragma: no cover
            pass
        self._thread.join(5.0)

    def status(self) -> Dict[int, Dict[str, Any]]:
        return {}

    def summary(self) -> Dict[str, Any]:
        return {"recorded_requests": self.table.requests, "distinct_requests": len(self.table.entries),
                "matched": self.matched, "unmatched": self.unmatched, "replies": self.replies}


def capture_from_pcap(path: str, protocol: str, baud: int) -> Any:
    """A :class:`fap_py.vbus.Capture` of the ``protocol`` packets of the monitor pcap at ``path``
    (their times from the first packet's; ``baud``: the header's, for the wire times)."""
    from ..monitor.pcap import read_pcap
    from ..vbus import Capture, CaptureRecord

    cap = Capture(header={"baud": str(baud)})
    t0: Optional[float] = None
    for frame in read_pcap(path):
        if frame.protocol != protocol:
            continue
        if frame.port is None:
            raise ReplayError(f"{path}: its packets do not name their sender port, so requests and "
                              "replies cannot be told apart (record a virtual bus, or a tap that knows "
                              "the ports)")
        t0 = frame.t if t0 is None else t0
        cap.records.append(CaptureRecord(int(round((frame.t - t0) * 1e6)), frame.port, frame.raw))
    return cap


def load_capture(path: Any, protocol: str, baud: Optional[int] = None) -> Any:
    """The capture at ``path``: a monitor pcap (by its magic) or a virtual-bus capture."""
    from .._validate import check_path
    from ..monitor.pcap import is_pcap
    from ..vbus import read_capture

    path = check_path(path, "capture path")
    if is_pcap(path):
        from .. import _protocols

        protocol = _protocols.get(protocol).name
        return capture_from_pcap(path, protocol, baud or _protocols.get(protocol).default_baud)
    return read_capture(path)


class Replay:
    """A replay on a new virtual bus (port0 for the master) or on ``port``; a context manager."""

    def __init__(self, capture_path: str, protocol: str, *, port: Optional[str] = None,
                 baud: Optional[int] = None, master_port: Optional[int] = None,
                 link_dir: Optional[str] = None, rs485: Any = None) -> None:
        from .. import _protocols
        from .._validate import check_baud, check_int
        from ..port import Port
        from ..vbus import MAX_PORTS

        if baud is not None:
            baud = check_baud(baud)
        if master_port is not None:
            master_port = check_int(master_port, "master_port (a port index of the capture)",
                                    0, MAX_PORTS - 1)
        proto = _protocols.get(protocol).name
        cap = load_capture(capture_path, proto, baud)
        table = build_table(cap, proto, master_port)
        line = baud or int(cap.header.get("baud", "0") or 0) or _protocols.get(proto).default_baud
        self.vbus = None
        self.master_port: Optional[str] = None
        if port is None:
            from ..vbus import VirtualBus

            self.vbus = VirtualBus(ports=2, baud=int(cap.header.get("baud", "0") or 0) or None,
                                   link_dir=link_dir)
            self.master_port, port = self.vbus.paths[0], self.vbus.paths[1]
        try:
            self.responder = ReplayResponder(proto, proto, Port(port, line, rs485), table)
        except BaseException:
            if self.vbus is not None:
                self.vbus.close()
            raise

    def close(self) -> None:
        self.responder.stop()
        if self.vbus is not None:
            self.vbus.close()

    def __enter__(self) -> "Replay":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
