"""One adapter per bus: it opens fap_py's own engine for the bus's protocol
and role, and turns what the engine does into bridge events. No protocol
logic lives here: framing, polling, retries and checks are the engines',
and each protocol's adapter is its bridge plug-in
(``fap_py.bridge.protocols.<name>.Adapter``, found through the protocol
table); this file holds what they share.

Each adapter has one worker thread that owns the engine's request side:
tx jobs run in arrival order, and for the request/response protocols
(exec async, G485, mikroC) the periodic polls run between them. A FAP node
also has a reader thread that waits on the engine's notification fd.
"""
from __future__ import annotations

import dataclasses
import logging
import queue
import threading
import time
from typing import Any, Dict, Mapping, Optional, Protocol, Tuple

from .. import _protocols
from .._validate import check_int, check_seconds
from ..errors import FapError, FapTimeoutError, InvalidTypeError, InvalidValueError
from .config import BusConfig

log = logging.getLogger(__name__)

_JOBS_MAX = 1000    # tx jobs waiting per bus; past that a tx is refused (error topic)

#: upper bounds (seconds) of the reply-time histogram buckets (Prometheus ``le``)
REPLY_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)

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
    def error(self, bus: str, node: int, tx_id: Optional[str], message: str, *,
              payload: Optional[bytes] = None, refused: bool = False) -> None: ...


def _check_req(req: Any, key: Any) -> None:
    if not isinstance(req, dict) or not isinstance(key, str):
        raise InvalidTypeError(f"a tx request is a dict and its key a str, not {type(req).__name__}, "
                               f"{type(key).__name__}")


def hex_field(req: Dict[str, Any], key: str = "data") -> bytes:
    """``req[key]`` (a hex string, default empty) as bytes; TxError otherwise."""
    _check_req(req, key)
    value = req.get(key, "")
    if not isinstance(value, str):
        raise TxError(f"{key} must be a hex string")
    try:
        return bytes.fromhex(value)
    except ValueError:
        raise TxError(f"{key} is not hex: {value!r}") from None


def int_field(req: Dict[str, Any], key: str, default: Any = ...) -> int:
    """``req[key]`` as an int (not a bool); TxError when missing without a default."""
    _check_req(req, key)
    value = req.get(key, default)
    if value is ...:
        raise TxError(f"missing {key!r}")
    if isinstance(value, bool) or not isinstance(value, int):
        raise TxError(f"{key} must be an integer")
    return value


def _check_cfg(cfg: Any) -> None:
    if not isinstance(cfg, BusConfig):
        raise InvalidTypeError(f"cfg must be a BusConfig, not {type(cfg).__name__}")


class BusAdapter:
    """The shared part: the job queue, the worker, counters, stop.

    A protocol's plug-in subclasses it as ``Adapter`` and names, in ``HEALTH``, its
    engine's counters behind each protocol-neutral bus health counter (stats
    ``health``, Prometheus, Home Assistant). Node numbers come from the protocol table.
    """

    #: protocol-neutral health counter -> the engine's own counter names (summed)
    HEALTH: Mapping[str, Tuple[str, ...]] = {}

    def __init__(self, cfg: BusConfig, sink: Sink) -> None:
        _check_cfg(cfg)
        self.proto = _protocols.get(cfg.protocol)
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
        node = check_int(node, "node", 0, 0xFF)   # one address byte
        c = self.nodes.get(node)
        if c is None:
            c = self.nodes[node] = NodeCounters()
        return c

    def configured_nodes(self) -> Tuple[int, ...]:
        """The nodes the configuration names (more may appear at run time)."""
        return ()

    def health_counters(self) -> Dict[str, int]:
        """The engine's counters under protocol-neutral names (only those this protocol has)."""
        stats = self.engine_stats()
        out = {}
        for name, keys in self.HEALTH.items():
            values = [stats[k] for k in keys if isinstance(stats.get(k), int)]
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
        """The engine's counters: every node's ``stats`` property is a frozen dataclass."""
        engine = self.engine
        if engine is None:   # the port is not open (yet)
            return {}
        try:
            return dataclasses.asdict(engine.stats)
        except FapError:     # closed under us
            return {}

    # -- tx ------------------------------------------------------------------------
    def _accepts(self, node: int) -> bool:
        """``node`` is an address a tx may go to: the protocol's node range or its broadcast."""
        p = self.proto
        return p.node_min <= node <= p.node_max or node == p.broadcast

    def check_node(self, node: int) -> None:
        """TxError unless ``node`` is a node number of this protocol and the bus runs."""
        if isinstance(node, bool) or not isinstance(node, int):
            raise InvalidTypeError(f"node must be an int, not {type(node).__name__}")
        if not self._accepts(node):
            p = self.proto
            extra = "" if p.broadcast is None else f" or {p.broadcast} (broadcast)"
            raise TxError(f"node {node} outside {p.node_min}..{p.node_max}{extra} for {p.name}")
        if not self.running:
            raise TxError(f"bus {self.cfg.name} is unavailable: {self.open_error}")

    def check_tx(self, node: int, req: Dict[str, Any]) -> None:
        """TxError unless ``req`` is a well-formed tx for ``node`` on this bus (its op, hex,
        sizes, and the protocol's own rules): checked before the tx id is recorded, so a
        refused tx uses up no id. The plug-ins add their rules in :meth:`_check_tx`."""
        if not isinstance(req, dict):
            raise InvalidTypeError(f"req must be a dict, not {type(req).__name__}")
        self.check_node(node)
        self._check_tx(node, req)

    def _check_tx(self, node: int, req: Dict[str, Any]) -> None:
        """The protocol's checks of a tx's form (nothing here: the engine checks at run time)."""

    def submit(self, node: int, tx_id: str, req: Dict[str, Any], deadline: Optional[float] = None,
               payload: Optional[bytes] = None) -> None:
        """Queue a tx for the worker (TxError if the queue is full); ``deadline`` (monotonic):
        the tx expires then (MQTT 5 message expiry) and is not run after it; ``payload``: the
        tx as received, echoed if the worker refuses it."""
        if not isinstance(tx_id, str):
            raise InvalidTypeError(f"tx_id must be a str, not {type(tx_id).__name__}")
        if not isinstance(req, dict):
            raise InvalidTypeError(f"req must be a dict, not {type(req).__name__}")
        if deadline is not None:
            check_seconds(deadline, "deadline", hi=1e15)   # a monotonic time
        if payload is not None and not isinstance(payload, bytes):
            raise InvalidTypeError(f"payload must be bytes or None, not {type(payload).__name__}")
        self.check_node(node)
        try:
            self.jobs.put_nowait((node, tx_id, req, deadline, payload))
        except queue.Full:
            raise TxError(f"bus {self.cfg.name}: {_JOBS_MAX} tx already waiting") from None

    def _run_tx(self, node: int, tx_id: str, req: Dict[str, Any], deadline: Optional[float],
                payload: Optional[bytes] = None) -> None:
        if deadline is not None and time.monotonic() > deadline:
            self.counters["tx_expired"] += 1
            self.sink.error(self.cfg.name, node, tx_id, "expired before it could run (MQTT message expiry)")
            return
        try:
            reply = self._execute(node, req)
        except InvalidValueError as exc:   # the tx's form (bad hex, empty, too long): refused
            self.sink.error(self.cfg.name, node, tx_id, f"{type(exc).__name__}: {exc}",
                            payload=payload, refused=True)
            return
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


def make_adapter(cfg: BusConfig, sink: Sink) -> BusAdapter:
    """The adapter of ``cfg.protocol``: its bridge plug-in's ``Adapter``."""
    _check_cfg(cfg)
    adapter: BusAdapter = _protocols.get(cfg.protocol).plugin("bridge").Adapter(cfg, sink)
    return adapter
