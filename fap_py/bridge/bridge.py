"""The bridge: buses on one side, the broker on the other (docs/bridge.md).

Topics under ``<prefix>``::

    <prefix>/<bus>/<node>/rx      a message or register read received (QoS, not retained)
    <prefix>/<bus>/<node>/tx      subscribed: messages to send, registers to write, Set commands
    <prefix>/<bus>/<node>/state   retained: {"state": "active"|"inactive", "last_seen": ...}
    <prefix>/<bus>/<node>/error   a tx that could not be carried out
    <prefix>/<bus>/stats          periodic counters
    <prefix>/<bus>/state          retained: {"state": "running"|"unavailable", "error": ...}
    <prefix>/bridge/<host>/status retained "online"; last will "offline"
    <prefix>/bridge/<host>/health retained: the outbox's health and each bus's state
"""
from __future__ import annotations

import json
import logging
import os
import threading
import time
from types import MappingProxyType
from typing import Any, Dict, List, Mapping, Optional, Tuple

from .._validate import check_bytes, check_seconds, check_timeout
from ..errors import FapError, InvalidTypeError, InvalidValueError
from .buses import BusAdapter, TxError, make_adapter
from .config import BridgeConfig, check_bus_node, verify_files
from .mqtt import MqttLink, paho
from .outputs import RX, SEEN, STATE, BridgeView, NodeEvent, NodeView, Output, build
from .store import Store, StoreError, now_iso

log = logging.getLogger(__name__)

TX_MAX = 64 << 10   #: bytes: a larger tx is refused before it is parsed
ECHO_MAX = 256      #: bytes of a refused tx echoed on the error topic
TEXT_MAX = 300      #: characters of an error text (published and logged)
ID_MAX = 128        #: characters of a tx id: a longer one is refused (the seen-id table stays small)


def _clip(text: str, limit: int = TEXT_MAX) -> str:
    """``text`` cut to ``limit`` characters, saying how much was cut."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _parse_tx(payload: bytes) -> Dict[str, Any]:
    """A tx payload as a JSON object; TxError saying plainly what it is not."""
    try:
        req = json.loads(payload)
    except UnicodeDecodeError as exc:
        raise TxError(f"payload is not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise TxError(f"payload is not JSON: {exc.msg} at character {exc.pos}") from None
    except ValueError as exc:   # an integer of more than 4300 digits
        raise TxError(f"payload is not usable JSON: {str(exc).split(':')[0]}") from None
    if not isinstance(req, dict):
        raise TxError("payload must be a JSON object")
    return req


def _describe(exc: BaseException) -> str:
    if isinstance(exc, RecursionError):
        return "TxError: JSON nested too deeply"
    return _clip(f"{type(exc).__name__}: {exc}")


class _Handler:
    """Messages on one topic an output subscribed to, to its ``on_message``."""

    __slots__ = ("output", "topic")

    def __init__(self, output: Output, topic: str) -> None:
        self.output, self.topic = output, topic

    def __call__(self, payload: bytes) -> None:
        self.output.on_message(self.topic, payload)


class Bridge:
    """Runs the buses of ``config`` and links them to the broker.

    A context manager: ``with Bridge(cfg) as b: b.wait_connected(10); ...``.
    :meth:`start` opens every bus first (a port that fails is published
    ``unavailable`` and retried in the background), then the broker link
    (the outputs the configuration asks for start first: :mod:`fap_py.bridge.outputs`);
    :meth:`stop` stops the buses and the outputs, waits up
    to ``drain`` seconds for the outbox to reach the broker, publishes
    ``offline`` and disconnects.
    """

    def __init__(self, config: BridgeConfig) -> None:
        self.config = config
        verify_files(config, ports=False)   # a missing CA names its key before anything is created
        paho()                              # paho-mqtt missing: said before the state file exists
        path = os.path.join(config.state_dir, f"fap-bridge-{config.host}.sqlite")
        self.store = Store(path, config.queue_max, config.seen_max)
        self._lock = threading.Lock()
        self._seq = self.store.next_seq()
        self._states: Dict[Tuple[str, int], List[Any]] = {}   # (bus, node) -> [active, last_seen, published]
        self.duplicates = 0
        self.tx_refused = 0
        self.not_stored = 0                      # publications the outbox could not take
        self.stopped = False                     # a clean stop published (health "stopped")
        self.store_error: Optional[str] = None   # the outbox's last error while it fails
        self._health_sent: Optional[Tuple[Any, ...]] = None
        self.buses: Dict[str, BusAdapter] = {b.name: make_adapter(b, self) for b in config.buses}
        try:
            self.link = MqttLink(config, self.store, self._on_tx)
        except BaseException:
            self.store.close()
            raise
        try:
            self._outputs: List[Output] = build(config)
        except BaseException:
            self.store.close()
            raise
        #: the running outputs by name (read-only)
        self.outputs: Mapping[str, Output] = MappingProxyType({o.name: o for o in self._outputs})
        self.view = BridgeView(self)   # what the outputs read of the bridge
        for o in self._outputs:
            for topic in o.subscriptions():
                self.link.extra[topic] = _Handler(o, topic)
        self.link.on_connected = self._on_connected
        self._stop = threading.Event()
        self._bus_lock = threading.Lock()        # opening a bus vs stopping the bridge
        self._stats_thread: Optional[threading.Thread] = None
        self._reopeners: List[threading.Thread] = []
        self._started: List[Output] = []

    # -- lifetime --------------------------------------------------------------------
    def start(self) -> "Bridge":
        """Open every bus (one whose port fails is published ``unavailable`` and retried in
        the background: the others run), then connect to the broker."""
        for o in self._outputs:   # before the buses: one that fails (a port taken) stops the start
            try:
                o.start(self.view)
            except BaseException:
                self._stop_outputs()
                self.store.close()
                raise
            self._started.append(o)
        for bus in self.buses.values():
            if not self._open_bus(bus):
                t = threading.Thread(target=self._reopen_loop, args=(bus,), daemon=True,
                                     name=f"fap-bridge-{bus.cfg.name}-reopen")
                t.start()
                self._reopeners.append(t)
        self.link.start()
        self._stats_thread = threading.Thread(target=self._stats_loop, name="fap-bridge-stats", daemon=True)
        self._stats_thread.start()
        log.info("bridge %s: %d bus(es), broker %s", self.config.host, len(self.buses),
                 ", ".join(b.address for b in self.config.brokers))
        return self

    def wait_connected(self, timeout: Optional[float] = None) -> bool:
        """True once the broker accepted us (BrokerRefusedError if it refused)."""
        return self.link.wait_connected(check_timeout(timeout))

    def _open_bus(self, bus: BusAdapter) -> bool:
        """Open and start ``bus``; False (state ``unavailable`` published) if its port fails."""
        with self._bus_lock:
            if self._stop.is_set():
                return True
            try:
                bus.open()
                bus.start()
            except (FapError, OSError) as exc:
                if bus.engine is not None:   # opened, then failed to start
                    bus.engine.close()
                    bus.engine = None
                first = bus.open_error is None
                bus.open_error = _clip(f"{type(exc).__name__}: {exc}")
                if first:
                    log.warning("bus %s: cannot open %s: %s (retrying every %g s; the other buses run)",
                                bus.cfg.name, _clip(bus.cfg.port, 100), bus.open_error, bus.cfg.reopen_interval)
                    self._bus_state(bus)
                else:
                    log.info("bus %s: cannot open %s: %s", bus.cfg.name, _clip(bus.cfg.port, 100), bus.open_error)
                return False
            was_down = bus.open_error is not None
            bus.open_error = None
        if was_down:
            log.warning("bus %s: %s opened", bus.cfg.name, _clip(bus.cfg.port, 100))
        self._bus_state(bus)
        return True

    def _reopen_loop(self, bus: BusAdapter) -> None:
        while not self._stop.wait(bus.cfg.reopen_interval):
            if self._open_bus(bus):
                return

    def _bus_state(self, bus: BusAdapter) -> None:
        state = "running" if bus.open_error is None else "unavailable"
        self._publish(self._topic(bus.cfg.name, None, "state"),
                      {"bus": bus.cfg.name, "state": state, "port": bus.cfg.port, "error": bus.open_error},
                      retain=True)
        self._publish_health()

    def alive(self) -> bool:
        """The bridge's own threads run (what the systemd watchdog vouches for)."""
        return (not self._stop.is_set() and self.link.alive()
                and self._stats_thread is not None and self._stats_thread.is_alive())

    def status_line(self) -> str:
        """One line for systemd's STATUS=: the broker, the buses, the outbox."""
        link = self.link
        where = "" if len(link.brokers) == 1 else \
            f" to {link.broker.address} ({link.broker_index + 1} of {len(link.brokers)})"
        broker = f"connected{where}" if link.connected else \
            f"not connected ({link.last_error or 'connecting' + where})"
        down = [n for n, b in self.buses.items() if b.open_error is not None]
        buses = f"{len(self.buses) - len(down)}/{len(self.buses)} buses running"
        if down:
            buses += f" (unavailable: {', '.join(down)})"
        store = "" if self.store_error is None else f", outbox failing: {self.not_stored} not stored"
        return _clip(f"broker {broker}; {buses}; outbox {self.store.pending}{store}")

    def _stop_buses(self) -> None:
        with self._bus_lock:
            for bus in self.buses.values():
                if not bus.running:
                    continue
                try:
                    bus.stop()
                except Exception:
                    log.exception("bus %s: stop failed", bus.cfg.name)

    def stop(self, drain: float = 5.0) -> None:
        """Stop the buses, drain the outbox (up to ``drain`` s), go offline."""
        drain = check_seconds(drain, "drain")
        if self._stop.is_set():
            return
        self._stop.set()
        self._stop_buses()
        for t in self._reopeners:
            t.join(5.0)
        if self._stats_thread is not None:
            self._stats_thread.join(5.0)
        self._stop_outputs()   # no more node events or ticks: nothing of theirs during the drain
        self._publish_stopped()
        if self.link.connected and not self.link.drain(drain):
            log.warning("stopping with %d publications still in the outbox %s (sent at next start)",
                        self.store.pending, self.store.path)
        self.link.stop()
        self.store.close()

    def output(self, name: str) -> Optional[Output]:
        """The running output called ``name`` (None when the configuration does not ask for it)."""
        if not isinstance(name, str):
            raise InvalidTypeError(f"name must be a str, not {type(name).__name__}")
        return self.outputs.get(name)

    def _stop_outputs(self) -> None:
        """Stop the started outputs, the last started first."""
        while self._started:
            o = self._started.pop()
            try:
                o.stop()
            except Exception:
                log.exception("output %s: stop failed", o.name)

    def _feed(self, bus: str, node: int, event: NodeEvent) -> None:
        """Tell every output of a node event (a failing one is logged, the others are told)."""
        if not self._outputs:
            return
        view = NodeView(self.buses[bus], node)
        for o in self._outputs:
            try:
                o.on_node_event(view, event)
            except Exception:
                log.exception("output %s: node event %s", o.name, event.kind)

    def _publish_stopped(self) -> None:
        """A clean stop: every active node's retained state becomes ``inactive`` (through
        the outbox, drained next) and the retained health says ``stopped``."""
        with self._lock:
            active = [(k, st[1]) for k, st in self._states.items() if st[0]]
            for k, _ in active:
                self._states[k][0] = False
        for (bus, node), seen in active:
            self._publish_state(bus, node, False, seen)
        self.stopped = True
        self._publish_health()

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
        """Number the publications and append them to the outbox in one transaction.

        If the outbox cannot take them (disk full, I/O error) they are counted in
        ``not_stored`` and the caller goes on: a bus reader never dies of a full disk,
        and delivery resumes by itself when a write succeeds again."""
        with self._lock:   # seq == outbox row: one order for both
            first = self._seq
            rows = []
            for topic, fields, retain in items:
                fields["seq"] = self._seq
                fields["host"] = self.config.host
                fields.setdefault("ts", now_iso())
                rows.append((topic, json.dumps(fields, separators=(",", ":")).encode(), retain))
                self._seq += 1
            try:
                self.store.put_many(rows)
            except StoreError as exc:
                self._seq = first          # rolled back: the numbers were not used
                self.not_stored += len(rows)
                changed = self.store_error is None
                self.store_error = _clip(str(exc))
                if changed:
                    log.error("%s: publications are counted as not stored until it works again", exc)
            else:
                changed = self.store_error is not None
                if changed:
                    log.warning("bridge state %s writable again (%d publications were not stored)",
                                self.store.path, self.not_stored)
                    self.store_error = None
        if changed:
            self._publish_health()
        self.link.notify()

    def health(self) -> Dict[str, Any]:
        """The bridge's own state, published retained on ``<prefix>/bridge/<host>/health``."""
        return {"host": self.config.host, "state": "stopped" if self.stopped else "running",
                "store": "ok" if self.store_error is None else "error",
                "store_error": self.store_error, "not_stored": self.not_stored,
                "buses": {name: {"state": "stopped" if self.stopped else
                                 "running" if b.open_error is None else "unavailable",
                                 "error": b.open_error} for name, b in self.buses.items()},
                "broker": self.link.broker.address, "broker_index": self.link.broker_index,
                "ts": now_iso()}

    def _publish_health(self, force: bool = True) -> None:
        """Publish :meth:`health` outside the outbox (it reports the outbox failing)."""
        doc = self.health()
        key = (doc["state"], doc["store"], doc["not_stored"], json.dumps(doc["buses"], sort_keys=True),
               doc["broker"])
        if not force and key == self._health_sent:
            return
        # remembered as sent only once handed to paho: one not sent (disconnected, held back
        # after a refusal) is sent at the next tick of the stats loop or the next connect
        sent = self.link.publish_now(self.link.health_topic, json.dumps(doc, separators=(",", ":")).encode())
        self._health_sent = key if sent else None

    def rx(self, bus: str, node: int, fields: Dict[str, Any]) -> None:
        """A message or register read received from ``node``."""
        self._check_bus(bus, node)
        if not isinstance(fields, dict):
            raise InvalidTypeError(f"fields must be a dict, not {type(fields).__name__}")
        self.rx_many(bus, [(node, fields)])

    def rx_many(self, bus: str, items: List[Tuple[int, Dict[str, Any]]]) -> None:
        """Several received messages, in bus order (one disk transaction)."""
        if not isinstance(items, list):
            raise InvalidTypeError(f"items must be a list of (node, fields), not {type(items).__name__}")
        for item in items:
            if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[1], dict)):
                raise InvalidTypeError("items must be a list of (node, fields)")
            self._check_bus(bus, item[0])
        t = time.time()
        ts = now_iso(t)
        for node in {node for node, _ in items}:
            self._seen(bus, node, t)
        self._publish_many([(self._topic(bus, node, "rx"), dict(fields, bus=bus, node=node, ts=ts), False)
                            for node, fields in items])
        if self._outputs:
            for node, fields in items:
                self._feed(bus, node, NodeEvent(RX, bus, node, fields=MappingProxyType(fields)))

    def _on_connected(self) -> None:
        self._publish_health()
        for o in self._outputs:
            try:
                o.on_connect(self.link)
            except Exception:
                log.exception("output %s: on_connect", o.name)

    def node_states(self) -> Dict[Tuple[str, int], bool]:
        """(bus, node) -> active, for every node whose state is known."""
        with self._lock:
            return {k: bool(st[0]) for k, st in self._states.items() if st[0] is not None}

    def _check_bus(self, bus: Any, node: Any) -> None:
        """A bus of this bridge and a node number (InvalidTypeError / InvalidValueError)."""
        check_bus_node(bus, node)
        if bus not in self.buses:
            raise InvalidValueError(f"no bus {bus[:40]!r} in this bridge")

    def _seen(self, bus: str, node: int, t: float) -> None:
        with self._lock:
            st = self._states.setdefault((bus, node), [None, None, None])
            st[1] = t
        if st[0] is not True:
            self.state(bus, node, True)

    def state(self, bus: str, node: int, active: bool) -> None:
        """Publish the retained state of ``node`` when it changes."""
        self._check_bus(bus, node)
        if not isinstance(active, bool):
            raise InvalidTypeError(f"active must be a bool, not {type(active).__name__}")
        self._feed(bus, node, NodeEvent(SEEN, bus, node))
        with self._lock:
            st = self._states.setdefault((bus, node), [None, None, None])
            if active:
                st[1] = time.time()
            if st[0] is active:
                return
            st[0] = active
            st[2] = st[1]
        self._publish_state(bus, node, active, st[1])
        self._feed(bus, node, NodeEvent(STATE, bus, node, active=active))

    def _publish_state(self, bus: str, node: int, active: bool, last_seen: Optional[float]) -> None:
        self._publish(self._topic(bus, node, "state"),
                      {"bus": bus, "node": node, "state": "active" if active else "inactive",
                       "last_seen": None if last_seen is None else now_iso(last_seen)}, retain=True)

    def error(self, bus: str, node: Any, tx_id: Optional[str], message: str,
              payload: Optional[bytes] = None, node_text: Optional[str] = None,
              refused: bool = False) -> None:
        """A tx that could not be carried out; ``payload``: the refused tx, echoed (bounded);
        ``refused``: refused for its form (counted in ``tx_refused``)."""
        # node: any int (a tx to node 99999 is refused here, by number), None if not a number
        if not isinstance(bus, str) or isinstance(node, bool) \
                or not (node is None or isinstance(node, int)):
            raise InvalidTypeError("error(): bus must be a str, node an int or None")
        if not all(v is None or isinstance(v, str) for v in (tx_id, node_text)) \
                or not isinstance(message, str):
            raise InvalidTypeError("error(): tx_id and node_text must be str or None, message a str")
        if payload is not None:
            payload = check_bytes(payload, "payload", 0, 1 << 62)
        if refused is not False and refused is not True:
            raise InvalidTypeError(f"refused must be a bool, not {type(refused).__name__}")
        if refused:
            with self._lock:
                self.tx_refused += 1
        message = _clip(message)
        tx_id = None if tx_id is None else _clip(tx_id, 100)
        log.warning("bus %s node %s: tx %s failed: %s", bus, node if node is not None else node_text,
                    tx_id, message)
        fields: Dict[str, Any] = {"bus": bus, "node": node, "id": tx_id, "error": message}
        if payload is not None:
            fields["payload"] = payload[:ECHO_MAX].decode("utf-8", "replace")
            fields["payload_bytes"] = len(payload)
        self._publish(f"{self.config.prefix}/{bus}/{node if node is not None else node_text}/error", fields)

    # -- tx (paho's network thread: quick, never blocks on a bus) -----------------------
    def _on_tx(self, topic: str, payload: bytes, deadline: Optional[float] = None) -> None:
        parts = topic.split("/")
        prefix = self.config.prefix.split("/")
        bus_name, node_text = parts[len(prefix)], parts[len(prefix) + 1]
        bus = self.buses.get(bus_name)
        if bus is None:
            return   # another bridge's bus on the same broker
        tx_id: Optional[str] = None
        node: Optional[int] = None
        try:
            # the payload first: an error names the tx's id whatever else is wrong with it
            if len(payload) > TX_MAX:
                raise TxError(f"payload of {len(payload)} bytes (at most {TX_MAX})")
            req = _parse_tx(payload)
            raw_id = req.get("id")
            if not isinstance(raw_id, bool) and isinstance(raw_id, (str, int)) and raw_id != "":
                tx_id = str(raw_id)
            if not (node_text.isascii() and node_text.isdigit()) or len(node_text) > 5:
                raise TxError(f"node {_clip(node_text, 40)!r} is not a node number")
            node = int(node_text)
            bus.check_node(node)
            if tx_id is None:
                raise TxError("every tx needs an \"id\" (string or integer)")
            if len(tx_id) > ID_MAX:
                raise TxError(f"id of {len(tx_id)} characters (at most {ID_MAX})")
            bus.check_tx(node, req)   # its form (op, hex, sizes): a refused tx uses up no id
            if not self.store.first_time(f"{bus_name}/{node}/{tx_id}"):
                self.duplicates += 1
                log.info("tx %s on %s: already executed (redelivery), ignored", tx_id, topic)
                return
            bus.submit(node, tx_id, req, deadline, payload)
        except Exception as exc:   # every malformed tx: bad JSON, too deep (RecursionError), store ...
            self.error(bus_name, node, tx_id, _describe(exc), payload, node_text=node_text, refused=True)

    # -- stats --------------------------------------------------------------------------
    def stats(self, bus: str) -> Dict[str, Any]:
        """The counters published on ``<prefix>/<bus>/stats``."""
        self._check_bus(bus, 0)
        adapter = self.buses[bus]
        return {"bus": bus, "state": "running" if adapter.open_error is None else "unavailable",
                "bridge": dict(adapter.counters, jobs_waiting=adapter.jobs.qsize()),
                "engine": adapter.engine_stats(), "health": adapter.health_counters(),
                "nodes": adapter.node_report(),
                "outbox": {"pending": self.store.pending, "dropped": self.store.dropped,
                           "not_stored": self.not_stored, "error": self.store_error},
                "broker": {"connected": self.link.connected, "connects": self.link.connects,
                           "address": self.link.broker.address, "index": self.link.broker_index,
                           "mqtt": "5" if self.link.v5 else "3.1.1", "switches": self.link.switches,
                           "fallbacks": self.link.fallbacks, "stalls": self.link.stalls,
                           "disconnects": self.link.disconnects, "published": self.link.published,
                           "refused": dict(self.link.refused_pubs),
                           "refused_own": dict(self.link.refused_own)},
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
            self._publish_health(force=False)
            for o in self._outputs:
                try:
                    o.on_tick()
                except Exception:
                    log.exception("output %s: on_tick", o.name)
