"""The Python responder of one bus: every node of a request/reply protocol on one port.

One thread reads the port (``fap_py.port.Port``, the C port layer), feeds the protocol
plug-in's request decoder, and for each request addressed to one of its nodes asks the fault
table (:meth:`~fap_py.sim._faults.FaultTable.draw`) what to do, then has the node build its
reply with the protocol's own encoder (the plug-in: no frame format is written here) and
writes it, damaged or late as the fault says. Exec async, mikroC and G485 nodes run here; FAP
slaves are the C engine's (:mod:`fap_py.sim.protocols.fap`).
"""
from __future__ import annotations

import logging
import random
import threading
from typing import Any, Dict, List, Optional

from ..errors import ClosedError, FapError, PortError
from ._faults import FaultTable

log = logging.getLogger("fap_py.sim")


class NodeStats:
    __slots__ = ("requests", "replies", "faults", "errors", "damaged")

    def __init__(self) -> None:
        self.requests = 0
        self.replies = 0
        self.faults: Dict[str, int] = {}
        self.errors = 0
        self.damaged = 0      # requests a direction-request fault damaged: not executed

    def public(self) -> Dict[str, Any]:
        return {"requests": self.requests, "replies": self.replies, "faults": dict(self.faults),
                "errors": self.errors, "requests_damaged": self.damaged}


class Request:
    """A decoded request: the node address it is for (None: every node hears it, no reply)
    and the protocol's own decoded object."""

    __slots__ = ("address", "obj")

    def __init__(self, address: Optional[int], obj: Any) -> None:
        self.address, self.obj = address, obj


class Responder:
    """Serve the nodes ``nodes`` (address -> plug-in node) of bus ``bus`` on ``port``."""

    def __init__(self, bus: str, plugin: Any, port: Any, nodes: Dict[int, Any], faults: FaultTable,
                 clock: Any, seed: int = 0) -> None:
        self.bus, self.plugin, self.port, self.nodes = bus, plugin, port, nodes
        self.faults, self.clock = faults, clock
        self.stats: Dict[int, NodeStats] = {a: NodeStats() for a in nodes}
        self.decoder = plugin.request_decoder(port.baudrate)
        self._rng = random.Random(seed)
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self.error: Optional[BaseException] = None
        self.unmatched = 0     # requests for addresses no node has
        #: notified after each batch of requests is handled (replies written): tests wait on it
        self.handled = threading.Condition()
        self.transactions = 0
        self.reopened = 0      # times the port was opened again after it went away
        self._timers: List[threading.Timer] = []
        # nodes that hear every request, not only their own (a G485 device losing the first
        # burst after power-on to baud detection, whoever it was for): empty for most buses
        self._overhear = [n for n in nodes.values() if getattr(n, "hears_all", False)]
        # a node whose address can change while it runs (G485: the ID register, an EEPROM
        # image loaded at reset) is found again under its new address after each request
        self._movable = bool(getattr(plugin, "ADDRESS_CAN_CHANGE", False))
        # (node, its counters) moved onto an address another node holds: both answer there,
        # as two devices at one ID do on a real bus
        self._parked: List[Any] = []
        if self._movable:              # an EEPROM image may hold another ID from the start
            self._rekey(list(self.nodes.items()))

    def start(self) -> "Responder":
        self._thread = threading.Thread(target=self._serve, name=f"fap-sim {self.bus}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._timers:
            t.cancel()
        try:
            self.port.close()
        except FapError:  # pragma: no cover
            pass
        if self._thread is not None:
            self._thread.join(5.0)

    def _serve(self) -> None:
        gone = False
        try:
            while not self._stop.is_set():
                # a partial frame expires after the decoder's idle time; otherwise wait long
                # (a close() from stop() ends the wait at once)
                wait = self.decoder.idle_timeout if getattr(self.decoder, "partial", False) else 1.0
                try:
                    data = self.port.read(4096, timeout=wait)
                except ClosedError:
                    return
                except PortError as exc:
                    if self._stop.is_set():
                        return
                    if not gone:      # once per outage, not once per try
                        log.warning("%s: %s; reopening", self.bus, exc)
                    gone = True
                    # no spinning while the device is away; then the same path again
                    if self._stop.wait(0.05):
                        return
                    try:
                        self.port.reopen()
                    except FapError:
                        continue
                    gone = False
                    self.reopened += 1
                    if hasattr(self.decoder, "clear"):
                        self.decoder.clear()   # a frame cut by the outage is not finished later
                    log.info("%s: port reopened", self.bus)
                    continue
                items = self.decoder.feed(data) if data else self.decoder.idle()
                for req in items:
                    self._handle(req)
                if items:
                    with self.handled:
                        self.transactions += len(items)
                        self.handled.notify_all()
        except BaseException as exc:   # reported in status, not swallowed
            if not self._stop.is_set():
                self.error = exc
                log.error("%s responder stopped: %s: %s", self.bus, type(exc).__name__, exc)

    def _handle(self, req: Request) -> None:
        if req.address is None:          # heard by every node (a broadcast, a discard)
            for node in (*self.nodes.values(), *(n for n, _ in self._parked)):
                node.hear(req.obj)
            if self._movable:
                self._rekey(list(self.nodes.items()))
            return
        node = self.nodes.get(req.address)
        for other in self._overhear:
            if other is not node:
                other.hear(req.obj)
        if node is None:
            self.unmatched += 1
            return
        self._transact(node, req, self.stats[req.address])
        if self._movable:
            for other, st in self._parked:
                if other.address == req.address:
                    self._transact(other, req, st)
            if node.address != req.address or self._parked:
                self._rekey([(req.address, node)])

    def _rekey(self, entries: List[Any]) -> None:
        """Put each (key, node) whose node's address is no longer its key under its address
        now; onto one already taken, the newcomer is parked: it answers there too (two devices
        at one ID, a conflict on a real bus; logged) and takes the address once it is free."""
        for key, node in entries:
            new = node.address
            if new == key or self.nodes.get(key) is not node:
                continue
            del self.nodes[key]
            st = self.stats.pop(key)
            if new in self.nodes:
                log.warning("%s: node %d moved to address %d, which another node holds: both "
                            "answer there", self.bus, key, new)
                self._parked.append((node, st))
                continue
            log.info("%s: node %d now answers at address %d", self.bus, key, new)
            self.nodes[new], self.stats[new] = node, st
        for entry in list(self._parked):
            node, st = entry
            if node.address not in self.nodes:
                self._parked.remove(entry)
                self.nodes[node.address], self.stats[node.address] = node, st

    def _transact(self, node: Any, req: Request, st: NodeStats) -> None:
        address = req.address
        assert address is not None     # _handle sends only addressed requests here
        main, late = self.faults.draw(self.bus, address)
        if main is not None:
            st.faults[main.kind] = st.faults.get(main.kind, 0) + 1
            if main.kind in ("off", "hung"):
                return
            if main.direction == "request":
                if self._request_damaged(main, req):
                    st.damaged += 1    # the node's check rejects it: not executed, no reply
                    return
                main = None            # it came through whole: an ordinary transaction
        st.requests += 1
        if main is not None and main.kind == "no_reply":
            node.answer(req.obj, self.clock.now())   # executed, not answered
            return
        if main is not None and main.kind == "error_reply":
            self.plugin.error_reply(node, main.word)   # the node's own error answer, by its rules
        try:
            frame = node.answer(req.obj, self.clock.now())
        except FapError as exc:        # a hook that raised: logged, counted, no reply
            st.errors += 1
            log.warning("%s node %d: %s", self.bus, address, exc)
            return
        if frame is None:
            return
        if main is not None:
            frame = self._damage(main, frame, req)
        pieces = [frame]
        if main is not None and main.kind == "split" and len(frame) > 1:
            pieces = [frame[:len(frame) // 2], frame[len(frame) // 2:]]
        delay = 0.0
        if late is not None:
            st.faults["late_reply"] = st.faults.get("late_reply", 0) + 1
            delay = late.ms / 1000.0
        if delay == 0.0 and len(pieces) == 1:
            self._write(frame, address, st)
            return
        if delay == 0.0:
            self._write(pieces[0], address, st, last=False)
            pieces = pieces[1:]
            delay = main.ms / 1000.0 if main is not None else 0.0
        # sent by a timer: the other nodes of the bus go on answering meanwhile
        self._later(delay, pieces, address, st, main.ms / 1000.0 if main is not None else 0.0)

    def _later(self, delay: float, pieces: List[bytes], address: int, st: NodeStats, gap: float) -> None:
        def fire() -> None:
            self._write(pieces[0], address, st, last=len(pieces) == 1)
            if len(pieces) > 1:
                self._later(gap, pieces[1:], address, st, gap)

        t = threading.Timer(delay, fire)
        t.daemon = True
        with self.handled:
            self._timers = [x for x in self._timers if x.is_alive()] + [t]
        t.start()

    def _write(self, frame: bytes, address: int, st: NodeStats, last: bool = True) -> None:
        if self._stop.is_set():
            return
        try:
            if frame:
                self.port.write(frame)
            if last:
                st.replies += 1
        except FapError as exc:
            log.warning("%s node %d: reply lost: %s", self.bus, address, exc)
        with self.handled:
            self.handled.notify_all()

    def _damage(self, fault: Any, frame: bytes, req: Request) -> bytes:
        k = fault.kind
        if k == "bad_crc":
            return self.plugin.bad_check(frame)
        if k == "wrong_address":
            return self.plugin.wrong_address(frame, req.address, req.obj)
        if k == "truncated":
            return frame[:max(1, len(frame) // 2)]
        if k == "garbage":
            return self.plugin.garbage(fault.rng, len(frame))
        if k == "bit_errors":
            out = bytearray(frame)
            for i in range(len(out)):
                if fault.rng.random() < fault.rate:
                    out[i] ^= 1 << fault.rng.randrange(8)
            return bytes(out)
        if k == "byte_drops":
            return bytes(b for b in frame if not fault.rng.random() < fault.rate)
        return frame

    def _request_damaged(self, fault: Any, req: Request) -> bool:
        """Whether ``fault`` (bit_errors or byte_drops on requests) hit at least one byte of
        the request as it crossed the wire; each byte is drawn as a reply's would be."""
        size = self.plugin.request_size(req.obj) if hasattr(self.plugin, "request_size") \
            else len(getattr(req.obj, "raw", b"")) or 1
        return any(fault.rng.random() < fault.rate for _ in range(size))

    def status(self) -> Dict[int, Any]:
        return {a: s.public() for a, s in self.stats.items()}


class CodecFramer:
    """Whole frames out of a byte stream by the C codec table's decoder of ``name``:
    ``feed(data) -> [(end offset in the stream, raw bytes)]`` (replay and learn)."""

    def __init__(self, name: str, baud: int) -> None:
        from .. import _codec

        self._dec = _codec.find(name).decoder(baud)
        self._frame = _codec.Frame

    def feed(self, data: bytes) -> List[Any]:
        return [(f.offset + len(f.raw), bytes(f.raw)) for f in self._dec.feed(data, 0)
                if isinstance(f, self._frame)]


def flip_to(frame: bytes, wanted: Any) -> bytes:
    """``frame`` with one bit flipped, the one nearest its end for which ``wanted(candidate)``
    (the protocol's own decoder says "bad check") holds: the check bytes are at the end."""
    for pos in range(len(frame) - 1, -1, -1):
        for bit in range(8):
            cand = bytearray(frame)
            cand[pos] ^= 1 << bit
            if wanted(bytes(cand)):
                return bytes(cand)
    raise FapError("no single-bit change of the frame gives a bad check")  # pragma: no cover


def garbage_without(rng: random.Random, n: int, avoid: bytes) -> bytes:
    """``n`` random bytes (at least 3) none of which is in ``avoid`` (frame start bytes)."""
    out = bytearray()
    while len(out) < max(3, n):
        b = rng.randrange(256)
        if b not in avoid:
            out.append(b)
    return bytes(out)
