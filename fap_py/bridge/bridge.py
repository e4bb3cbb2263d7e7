"""The bridge: buses on one side, the broker on the other (docs/bridge.md).

Topics under ``<prefix>``::

    <prefix>/<bus>/<node>/rx      a message or register read received (QoS, not retained)
    <prefix>/<bus>/<node>/tx      subscribed: messages to send, registers to write, Set commands
    <prefix>/<bus>/<node>/state   retained: {"state": "active"|"inactive", "last_seen": ...}
    <prefix>/<bus>/<node>/error   a tx that could not be carried out
    <prefix>/<bus>/stats          periodic counters
    <prefix>/bridge/<host>/status retained "online"; last will "offline"
"""
from __future__ import annotations

import json
import logging
import os
import threading
import time
from typing import Any, Dict, List, Optional, Tuple

from ..errors import FapError
from .buses import BusAdapter, TxError, make_adapter
from .config import BridgeConfig
from .mqtt import MqttLink
from .store import Store, now_iso

log = logging.getLogger(__name__)


class Bridge:
    """Runs the buses of ``config`` and links them to the broker.

    A context manager: ``with Bridge(cfg) as b: b.wait_connected(10); ...``.
    :meth:`start` opens every bus first (a port error raises before anything
    connects), then the broker link; :meth:`stop` stops the buses, waits up
    to ``drain`` seconds for the outbox to reach the broker, publishes
    ``offline`` and disconnects.
    """

    def __init__(self, config: BridgeConfig) -> None:
        self.config = config
        path = os.path.join(config.state_dir, f"fap-bridge-{config.host}.sqlite")
        self.store = Store(path, config.queue_max, config.seen_max)
        self._lock = threading.Lock()
        self._seq = self.store.next_seq()
        self._states: Dict[Tuple[str, int], List[Any]] = {}   # (bus, node) -> [active, last_seen, published]
        self.duplicates = 0
        self.tx_refused = 0
        self.buses: Dict[str, BusAdapter] = {b.name: make_adapter(b, self) for b in config.buses}
        self.link = MqttLink(config, self.store, self._on_tx)
        self._stop = threading.Event()
        self._stats_thread: Optional[threading.Thread] = None
        self._started: List[BusAdapter] = []

    # -- lifetime --------------------------------------------------------------------
    def start(self) -> "Bridge":
        try:
            for bus in self.buses.values():
                bus.open()
                self._started.append(bus)
            for bus in self._started:
                bus.start()
        except BaseException:
            self._stop_buses()
            self.store.close()
            raise
        self.link.start()
        self._stats_thread = threading.Thread(target=self._stats_loop, name="fap-bridge-stats", daemon=True)
        self._stats_thread.start()
        log.info("bridge %s: %d bus(es), broker %s:%d", self.config.host, len(self.buses),
                 self.config.broker.host, self.config.broker.port)
        return self

    def wait_connected(self, timeout: Optional[float] = None) -> bool:
        """True once the broker accepted us (BrokerRefusedError if it refused)."""
        return self.link.wait_connected(timeout)

    def _stop_buses(self) -> None:
        for bus in self._started:
            try:
                bus.stop()
            except Exception:
                log.exception("bus %s: stop failed", bus.cfg.name)
        self._started = []

    def stop(self, drain: float = 5.0) -> None:
        """Stop the buses, drain the outbox (up to ``drain`` s), go offline."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._stop_buses()
        if self._stats_thread is not None:
            self._stats_thread.join(5.0)
        if self.link.connected and not self.link.drain(drain):
            log.warning("stopping with %d publications still in the outbox %s (sent at next start)",
                        self.store.pending, self.store.path)
        self.link.stop()
        self.store.close()

    def __enter__(self) -> "Bridge":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- publications (called by the adapters' threads) --------------------------------
    def _topic(self, bus: str, node: Optional[int], leaf: str) -> str:
        middle = bus if node is None else f"{bus}/{node}"
        return f"{self.config.prefix}/{middle}/{leaf}"

    def _publish(self, topic: str, fields: Dict[str, Any], retain: bool = False) -> None:
        self._publish_many([(topic, fields, retain)])

    def _publish_many(self, items: List[Tuple[str, Dict[str, Any], bool]]) -> None:
        """Number the publications and append them to the outbox in one transaction."""
        with self._lock:   # seq == outbox row: one order for both
            rows = []
            for topic, fields, retain in items:
                fields["seq"] = self._seq
                fields["host"] = self.config.host
                fields.setdefault("ts", now_iso())
                rows.append((topic, json.dumps(fields, separators=(",", ":")).encode(), retain))
                self._seq += 1
            self.store.put_many(rows)
        self.link.notify()

    def rx(self, bus: str, node: int, fields: Dict[str, Any]) -> None:
        """A message or register read received from ``node``."""
        self.rx_many(bus, [(node, fields)])

    def rx_many(self, bus: str, items: List[Tuple[int, Dict[str, Any]]]) -> None:
        """Several received messages, in bus order (one disk transaction)."""
        t = time.time()
        ts = now_iso(t)
        for node in {node for node, _ in items}:
            self._seen(bus, node, t)
        self._publish_many([(self._topic(bus, node, "rx"), dict(fields, bus=bus, node=node, ts=ts), False)
                            for node, fields in items])

    def _seen(self, bus: str, node: int, t: float) -> None:
        with self._lock:
            st = self._states.setdefault((bus, node), [None, None, None])
            st[1] = t
        if st[0] is not True:
            self.state(bus, node, True)

    def state(self, bus: str, node: int, active: bool) -> None:
        """Publish the retained state of ``node`` when it changes."""
        with self._lock:
            st = self._states.setdefault((bus, node), [None, None, None])
            if active:
                st[1] = time.time()
            if st[0] is active:
                return
            st[0] = active
            st[2] = st[1]
        self._publish_state(bus, node, active, st[1])

    def _publish_state(self, bus: str, node: int, active: bool, last_seen: Optional[float]) -> None:
        self._publish(self._topic(bus, node, "state"),
                      {"bus": bus, "node": node, "state": "active" if active else "inactive",
                       "last_seen": None if last_seen is None else now_iso(last_seen)}, retain=True)

    def error(self, bus: str, node: int, tx_id: Optional[str], message: str) -> None:
        """A tx that could not be carried out."""
        log.warning("bus %s node %d: tx %s failed: %s", bus, node, tx_id, message)
        self._publish(self._topic(bus, node, "error"),
                      {"bus": bus, "node": node, "id": tx_id, "error": message})

    # -- tx (paho's network thread: quick, never blocks on a bus) -----------------------
    def _on_tx(self, topic: str, payload: bytes) -> None:
        parts = topic.split("/")
        prefix = self.config.prefix.split("/")
        bus_name, node_text = parts[len(prefix)], parts[len(prefix) + 1]
        bus = self.buses.get(bus_name)
        if bus is None:
            return   # another bridge's bus on the same broker
        tx_id: Optional[str] = None
        try:
            node = int(node_text)
        except ValueError:
            log.warning("tx on %s: node %r is not a number", topic, node_text)
            return
        try:
            req = json.loads(payload)
            if not isinstance(req, dict):
                raise TxError("payload must be a JSON object")
            raw_id = req.get("id")
            if isinstance(raw_id, bool) or not isinstance(raw_id, (str, int)) or raw_id == "":
                raise TxError("every tx needs an \"id\" (string or integer)")
            tx_id = str(raw_id)
            if not self.store.first_time(f"{bus_name}/{node}/{tx_id}"):
                self.duplicates += 1
                log.info("tx %s on %s: already executed (redelivery), ignored", tx_id, topic)
                return
            bus.submit(node, tx_id, req)
        except (ValueError, FapError) as exc:   # json.JSONDecodeError is a ValueError
            self.tx_refused += 1
            self.error(bus_name, node, tx_id, f"{type(exc).__name__}: {exc}")

    # -- stats --------------------------------------------------------------------------
    def stats(self, bus: str) -> Dict[str, Any]:
        """The counters published on ``<prefix>/<bus>/stats``."""
        adapter = self.buses[bus]
        return {"bus": bus, "bridge": dict(adapter.counters, jobs_waiting=adapter.jobs.qsize()),
                "engine": adapter.engine_stats(),
                "outbox": {"pending": self.store.pending, "dropped": self.store.dropped},
                "broker": {"connected": self.link.connected, "connects": self.link.connects,
                           "disconnects": self.link.disconnects, "published": self.link.published},
                "tx_duplicates": self.duplicates, "tx_refused": self.tx_refused}

    def _stats_loop(self) -> None:
        while not self._stop.wait(self.config.stats_interval):
            if not self.link.connected:
                continue   # periodic: a missed round is not queued
            for name in self.buses:
                try:
                    self._publish(self._topic(name, None, "stats"), self.stats(name))
                except FapError as exc:
                    log.warning("stats of bus %s: %s", name, exc)
            with self._lock:   # refresh last_seen of the active nodes in their retained state
                stale = [(k, st[1]) for k, st in self._states.items() if st[0] and st[1] != st[2]]
                for k, _ in stale:
                    self._states[k][2] = self._states[k][1]
            for (bus, node), seen in stale:
                self._publish_state(bus, node, True, seen)
