"""One adapter per bus: it opens fap_py's own engine for the bus's protocol
and role, and turns what the engine does into bridge events. No protocol
logic lives here: framing, polling, retries and checks are the engines'.

Each adapter has one worker thread that owns the engine's request side:
tx jobs run in arrival order, and for the request/response protocols
(exec async, G485, mikroC) the periodic polls run between them. A FAP node
also has a reader thread that waits on the engine's notification fd.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import queue
import select
import threading
import time
from typing import Any, Dict, List, Optional, Protocol, Tuple

from .._validate import check_int, check_seconds
from ..errors import FapError, FapTimeoutError, InvalidTypeError, InvalidValueError
from .config import BusConfig

log = logging.getLogger(__name__)

_JOBS_MAX = 1000    # tx jobs waiting per bus; past that a tx is refused (error topic)

#: upper bounds (seconds) of the reply-time histogram buckets (Prometheus ``le``)
REPLY_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)

# The engines' own counter names behind each protocol-neutral bus health counter
# (stats "health", Prometheus, Home Assistant).
_HEALTH: Dict[str, Dict[str, Tuple[str, ...]]] = {
    "frames_rx": {"fap": ("frames_rx",), "execasync": ("rx_frames",), "mikroc": ("frames",)},
    "frames_tx": {"fap": ("frames_tx",), "execasync": ("tx_frames",), "g485": ("transactions",)},
    "crc_errors": {"fap": ("crc_errors",), "execasync": ("corrupt",),
                   "g485": ("frame_errors", "check_mismatches"), "mikroc": ("damaged",)},
    "timeouts": {"fap": ("id_timeouts", "data_done_timeouts"), "execasync": ("timeouts",),
                 "g485": ("no_response",)},
    "retries": {"execasync": ("retries",), "g485": ("retries",)},
    "collisions": {"fap": ("collisions",)},
}


class NodeCounters:
    """What the bridge saw of one node: messages each way, failures, reply times."""

    def __init__(self) -> None:
        self.rx = 0
        self.tx = 0
        self.errors = 0
        self.timeouts = 0
        self.buckets = [0] * len(REPLY_BUCKETS)   # non-cumulative; the exporter sums
        self.reply_sum = 0.0
        self.reply_count = 0
        self.last_reply: Optional[float] = None   # seconds

    def reply(self, seconds: float) -> None:
        seconds = check_seconds(seconds, "seconds")   # a NaN would poison the sum and buckets
        for i, le in enumerate(REPLY_BUCKETS):
            if seconds <= le:
                self.buckets[i] += 1
                break
        self.reply_sum += seconds
        self.reply_count += 1
        self.last_reply = seconds

    def report(self) -> Dict[str, Any]:
        """The node's counters as published in stats (``reply_ms``: the last reply time)."""
        return {"rx": self.rx, "tx": self.tx, "errors": self.errors, "timeouts": self.timeouts,
                "replies": self.reply_count,
                "reply_ms": None if self.last_reply is None else round(self.last_reply * 1000, 3)}

    def failed(self, exc: BaseException) -> None:
        self.errors += 1
        if isinstance(exc, FapTimeoutError) or "NoResponse" in type(exc).__name__:
            self.timeouts += 1


class TxError(InvalidValueError):
    """A tx request is malformed or cannot apply to this bus (published on the error topic)."""


class Sink(Protocol):
    """What an adapter reports to (the bridge)."""

    def rx(self, bus: str, node: int, fields: Dict[str, Any]) -> None: ...
    def rx_many(self, bus: str, items: list) -> None: ...
    def state(self, bus: str, node: int, active: bool) -> None: ...
    def error(self, bus: str, node: int, tx_id: Optional[str], message: str) -> None: ...


def _hex(req: Dict[str, Any], key: str = "data") -> bytes:
    value = req.get(key, "")
    if not isinstance(value, str):
        raise TxError(f"{key} must be a hex string")
    try:
        return bytes.fromhex(value)
    except ValueError:
        raise TxError(f"{key} is not hex: {value!r}") from None


def _int(req: Dict[str, Any], key: str, default: Any = ...) -> int:
    value = req.get(key, default)
    if value is ...:
        raise TxError(f"missing {key!r}")
    if isinstance(value, bool) or not isinstance(value, int):
        raise TxError(f"{key} must be an integer")
    return value


def _check_cfg(cfg: Any) -> None:
    if not isinstance(cfg, BusConfig):
        raise InvalidTypeError(f"cfg must be a BusConfig, not {type(cfg).__name__}")


def _stats(obj: Any) -> Dict[str, Any]:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return dataclasses.asdict(obj)
    return dict(obj.as_dict()) if hasattr(obj, "as_dict") else {}


class BusAdapter:
    """The shared part: the job queue, the worker, counters, stop."""

    nodes_lo, nodes_hi = 0, 255

    def __init__(self, cfg: BusConfig, sink: Sink) -> None:
        _check_cfg(cfg)
        if not all(callable(getattr(sink, m, None)) for m in ("rx", "rx_many", "state", "error")):
            raise InvalidTypeError(f"sink must have rx, rx_many, state and error methods, "
                                   f"not {type(sink).__name__}")
        self.cfg = cfg
        self.sink = sink
        self.engine: Any = None
        self.jobs: "queue.Queue[Optional[tuple]]" = queue.Queue(_JOBS_MAX)
        self._stop = threading.Event()
        self._threads: list = []
        self.counters = {"rx": 0, "tx": 0, "tx_errors": 0, "tx_expired": 0, "poll_errors": 0,
                         "rx_overflow": 0, "reader_errors": 0}
        self.nodes: Dict[int, NodeCounters] = {}
        self.running = False
        self.open_error: Optional[str] = None   #: why the port could not be opened (None: open)

    def node(self, node: int) -> NodeCounters:
        """The counters of ``node`` (created on first use)."""
        node = check_int(node, "node", 0, 255)
        c = self.nodes.get(node)
        if c is None:
            c = self.nodes[node] = NodeCounters()
        return c

    def configured_nodes(self) -> Tuple[int, ...]:
        """The nodes the configuration names (more may appear at run time)."""
        c = self.cfg
        if c.protocol == "fap":
            return c.slaves if c.role == "master" else (0,)
        if c.protocol == "g485":
            return tuple(d.address for d in c.devices)
        return c.nodes

    def health_counters(self) -> Dict[str, int]:
        """The engine's counters under protocol-neutral names (only those this protocol has)."""
        stats = self.engine_stats()
        out = {}
        for name, per_proto in _HEALTH.items():
            values = [stats[k] for k in per_proto.get(self.cfg.protocol, ()) if isinstance(stats.get(k), int)]
            if values:
                out[name] = sum(values)
        return out

    def node_report(self) -> Dict[str, Dict[str, Any]]:
        """Every known node's counters, keyed by the node number as text."""
        for node in self.configured_nodes():
            self.node(node)
        return {str(n): c.report() for n, c in sorted(self.nodes.items())}

    def _timed(self, node: int, call: Any, *args: Any, **kw: Any) -> Any:
        """``call(*args)``, its time recorded as ``node``'s reply time; a failure counted."""
        t0 = time.monotonic()
        try:
            result = call(*args, **kw)
        except FapError as exc:
            self.node(node).failed(exc)
            raise
        self.node(node).reply(time.monotonic() - t0)
        return result

    # -- lifetime ------------------------------------------------------------
    def open(self) -> None:
        """Open the engine (raises PortError and friends)."""
        raise NotImplementedError

    def start(self) -> None:
        self._spawn(self._worker, "worker")
        self.running = True

    def _spawn(self, target: Any, what: str) -> None:
        t = threading.Thread(target=target, name=f"fap-bridge-{self.cfg.name}-{what}", daemon=True)
        t.start()
        self._threads.append(t)

    def stop(self) -> None:
        self._stop.set()
        try:
            self.jobs.put_nowait(None)
        except queue.Full:
            pass
        for t in self._threads:
            t.join(5.0)
        if self.engine is not None:
            self.engine.close()

    def engine_stats(self) -> Dict[str, Any]:
        if self.engine is None:   # the port is not open (yet)
            return {}
        try:
            return _stats(self.engine.stats)   # every node: a stats property (docs/python.md)
        except FapError:
            return {}

    # -- tx ------------------------------------------------------------------------
    def check_node(self, node: int) -> None:
        """TxError unless ``node`` is a node number of this protocol and the bus runs."""
        if isinstance(node, bool) or not isinstance(node, int):
            raise InvalidTypeError(f"node must be an int, not {type(node).__name__}")
        if not self.nodes_lo <= node <= self.nodes_hi:
            raise TxError(f"node {node} outside {self.nodes_lo}..{self.nodes_hi} for {self.cfg.protocol}")
        if not self.running:
            raise TxError(f"bus {self.cfg.name} is unavailable: {self.open_error}")

    def submit(self, node: int, tx_id: str, req: Dict[str, Any], deadline: Optional[float] = None) -> None:
        """Queue a tx for the worker (TxError if the queue is full); ``deadline`` (monotonic):
        the tx expires then (MQTT 5 message expiry) and is not run after it."""
        if not isinstance(tx_id, str):
            raise InvalidTypeError(f"tx_id must be a str, not {type(tx_id).__name__}")
        if not isinstance(req, dict):
            raise InvalidTypeError(f"req must be a dict, not {type(req).__name__}")
        if deadline is not None:
            check_seconds(deadline, "deadline", hi=1e15)   # a monotonic time
        self.check_node(node)
        try:
            self.jobs.put_nowait((node, tx_id, req, deadline))
        except queue.Full:
            raise TxError(f"bus {self.cfg.name}: {_JOBS_MAX} tx already waiting") from None

    def _run_tx(self, node: int, tx_id: str, req: Dict[str, Any], deadline: Optional[float]) -> None:
        if deadline is not None and time.monotonic() > deadline:
            self.counters["tx_expired"] += 1
            self.sink.error(self.cfg.name, node, tx_id, "expired before it could run (MQTT message expiry)")
            return
        try:
            reply = self._execute(node, req)
        except FapError as exc:
            self.counters["tx_errors"] += 1
            self.sink.error(self.cfg.name, node, tx_id, f"{type(exc).__name__}: {exc}")
            return
        self.counters["tx"] += 1
        self.node(node).tx += 1
        if reply is not None:
            self.counters["rx"] += 1
            self.sink.rx(self.cfg.name, node, dict(reply, reply_to=tx_id))

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        """Carry out one tx; the fields of the reply to publish on rx, or None."""
        raise NotImplementedError

    def poll(self) -> None:
        """One round of periodic polls (request/response protocols)."""

    def _polls(self) -> bool:
        return False

    def _worker(self) -> None:
        interval = self.cfg.poll_interval
        next_poll = time.monotonic()
        while not self._stop.is_set():
            wait = max(0.0, next_poll - time.monotonic()) if self._polls() else None
            try:
                job = self.jobs.get(timeout=wait)
            except queue.Empty:
                job = ()
            if job is None or self._stop.is_set():
                return
            if job:
                self._run_tx(*job)
            if self._polls() and time.monotonic() >= next_poll:
                try:
                    self.poll()
                except Exception:   # a poll bug must not stop the tx worker
                    log.exception("bus %s: poll failed", self.cfg.name)
                next_poll = max(next_poll + interval, time.monotonic())

    def _polled(self, node: int, fields: Optional[Dict[str, Any]], exc: Optional[Exception]) -> None:
        if exc is None:
            self.counters["rx"] += 1
            self.node(node).rx += 1
            self.sink.state(self.cfg.name, node, True)
            if fields is not None:
                self.sink.rx(self.cfg.name, node, fields)
        else:
            self.counters["poll_errors"] += 1
            log.debug("bus %s: poll of node %d failed: %s", self.cfg.name, node, exc)
            self.sink.state(self.cfg.name, node, False)


class FapAdapter(BusAdapter):
    """FAP master (polls its slaves) or slave (answers the master): fap_py.Master / fap_py.Slave."""

    nodes_lo, nodes_hi = 0, 31

    def open(self) -> None:
        from ..fap import Master, Slave

        c = self.cfg
        if c.role == "master":
            self.engine = Master(c.port, c.baud, slaves=c.slaves, rs485=c.rs485,
                                 id_cycle=c.id_cycle, data_done_timeout=c.data_done_timeout)
            for sid in c.slaves:
                self.sink.state(c.name, sid, False)
        else:
            self.engine = Slave(c.port, c.baud, id=c.id, rs485=c.rs485)

    _wake: Optional[Tuple[int, int]] = None   # a pipe that wakes the reader at stop

    def start(self) -> None:
        self._wake = os.pipe()
        super().start()
        self._spawn(self._reader, "reader")

    def stop(self) -> None:
        self._stop.set()
        if self._wake is not None:
            os.write(self._wake[1], b"x")
        super().stop()
        if self._wake is not None:
            for fd in self._wake:
                os.close(fd)
            self._wake = None

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        op = req.get("op", "send")
        if op != "send":
            raise TxError(f"op {op!r}: a fap bus only sends")
        self.engine.send(_hex(req), to=node, timeout=self.cfg.timeout)
        return None

    def _reader(self) -> None:
        from ..fap import EventKind

        eng, name, wake = self.engine, self.cfg.name, self._wake
        if wake is None:   # start() opens the pipe before the reader runs
            return
        poller = select.poll()
        poller.register(eng.fileno(), select.POLLIN)
        poller.register(wake[0], select.POLLIN)
        active = {EventKind.SLAVE_ACTIVE: True, EventKind.SLAVE_INACTIVE: False,
                  EventKind.ID_TIMEOUT: False}
        while not self._stop.is_set():
            poller.poll(1000)
            if self._stop.is_set():
                return
            try:
                batch: List[Tuple[int, Dict[str, Any]]] = []
                while len(batch) < 500:     # what is queued now: one disk transaction
                    msg = eng.recv_nowait()
                    if msg is None:
                        break
                    batch.append((msg.source, {"data": msg.data.hex()}))
                if batch:
                    self.counters["rx"] += len(batch)
                    for source, _ in batch:
                        self.node(source).rx += 1
                    self.sink.rx_many(name, batch)
                for ev in eng.events(0):
                    if ev.kind in active:
                        self.sink.state(name, ev.id, active[ev.kind])
                    elif ev.kind == EventKind.QUERIED:
                        self.sink.state(name, 0, True)
                    elif ev.kind == EventKind.RX_OVERFLOW:   # counted in engine.rx_dropped
                        self.counters["rx_overflow"] += 1
                        if self.counters["rx_overflow"] == 1:
                            log.warning("bus %s: receive queue full, messages dropped (the bridge is "
                                        "slower than the bus); see stats engine.rx_dropped", name)
                    elif ev.kind in (EventKind.PORT_LOST, EventKind.PORT_REOPENED):
                        log.warning("bus %s: %s", name, ev)
            except FapError as exc:   # closed under us at stop
                if not self._stop.is_set():
                    log.error("bus %s: reader stopped: %s", name, exc)
                return
            except Exception:   # the reader outlives any one failure (it is the bus's only reader)
                self.counters["reader_errors"] += 1
                if self.counters["reader_errors"] <= 3:
                    log.exception("bus %s: reader error (it goes on reading)", name)


class ExecAsyncAdapter(BusAdapter):
    """Exec async master: fap_py.execasync.Master; polls ``nodes`` with ``poll_data``."""

    nodes_lo, nodes_hi = 1, 255   # 255 = broadcast

    def open(self) -> None:
        from ..execasync import Master

        c = self.cfg
        self.engine = Master(c.port, c.baud, timeout=c.timeout, retries=c.retries, rs485=c.rs485)

    def _polls(self) -> bool:
        return self.cfg.poll_data is not None and bool(self.cfg.nodes)

    def poll(self) -> None:
        for node in self.cfg.nodes:
            try:
                reply = self._timed(node, self.engine.transact, node, self.cfg.poll_data)
            except FapError as exc:
                self._polled(node, None, exc)
            else:
                self._polled(node, {"data": reply.hex()}, None)

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        op = req.get("op", "send")
        if op != "send":
            raise TxError(f"op {op!r}: an execasync bus only sends")
        data = _hex(req)
        if node == 255:
            self.engine.broadcast(data)
            return {"data": ""}
        reply = self._timed(node, self.engine.transact, node, data)
        self.sink.state(self.cfg.name, node, True)
        return {"data": reply.hex()}


class MikrocAdapter(BusAdapter):
    """mikroC RS-485 master: fap_py.mikroc.Master; request/reply, polls ``nodes``."""

    def open(self) -> None:
        from ..mikroc import Master

        c = self.cfg
        self.engine = Master(c.port, c.baud, rs485=c.rs485)

    def _polls(self) -> bool:
        return self.cfg.poll_data is not None and bool(self.cfg.nodes)

    def poll(self) -> None:
        for node in self.cfg.nodes:
            try:
                reply = self._timed(node, self.engine.request, node, self.cfg.poll_data,
                                   timeout=self.cfg.timeout)
            except FapError as exc:
                self._polled(node, None, exc)
            else:
                self._polled(node, {"data": reply.data.hex()}, None)

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        from ..mikroc import BROADCAST

        op = req.get("op", "send")
        if op != "send":
            raise TxError(f"op {op!r}: a mikroc bus only sends")
        data = _hex(req)
        if node == BROADCAST:
            self.engine.send(node, data)
            return {"data": ""}
        reply = self._timed(node, self.engine.request, node, data, timeout=self.cfg.timeout)
        return {"data": reply.data.hex()}


class G485Adapter(BusAdapter):
    """G485 master: fap_py.g485.G485Master; polls the configured register runs."""

    nodes_lo, nodes_hi = 0, 126   # 0 = broadcast (write and set only)

    def open(self) -> None:
        from ..g485 import G485Master

        c = self.cfg
        self.engine = G485Master(c.port, c.baud, timeout=c.timeout, retries=c.retries, rs485=c.rs485)

    def engine_stats(self) -> Dict[str, Any]:
        return {} if self.engine is None else _stats(self.engine.stats)

    def _polls(self) -> bool:
        return any(d.registers for d in self.cfg.devices)

    def poll(self) -> None:
        for dev in self.cfg.devices:
            for first, count in dev.registers:
                try:
                    data = self._timed(dev.address, self.engine.read, dev.address, first, count)
                except FapError as exc:
                    self._polled(dev.address, None, exc)
                    break          # the device is not answering: skip its other runs this round
                self._polled(dev.address, {"op": "read", "register": first, "data": data.hex()}, None)

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        m = self.engine
        op = req.get("op")
        if op == "read":
            register, count = _int(req, "register"), _int(req, "count", 1)
            return {"op": op, "register": register,
                    "data": self._timed(node, m.read, node, register, count).hex()}
        if op == "write":
            register, data = _int(req, "register"), _hex(req)
            if node == 0:
                m.broadcast_write(register, data)
            else:
                self._timed(node, m.write, node, register, data)
            return {"op": op, "register": register, "data": data.hex()}
        if op == "set":
            command = req.get("command")
            if not isinstance(command, (str, int)) or isinstance(command, bool):
                raise TxError("set needs a command (a SetCommand name or value)")
            if node == 0:
                m.broadcast_set(command)
            else:
                m.set(node, command)
            return {"op": op, "command": command, "data": ""}
        if op == "error_word":
            return {"op": op, "value": m.error_word(node), "data": ""}
        raise TxError(f"op {op!r}: a g485 bus takes read, write, set or error_word")


ADAPTERS = {"fap": FapAdapter, "execasync": ExecAsyncAdapter, "g485": G485Adapter, "mikroc": MikrocAdapter}


def make_adapter(cfg: BusConfig, sink: Sink) -> BusAdapter:
    """The adapter for ``cfg.protocol``."""
    _check_cfg(cfg)
    return ADAPTERS[cfg.protocol](cfg, sink)
