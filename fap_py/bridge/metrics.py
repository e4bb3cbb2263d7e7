"""Prometheus metrics of the bridge (``[metrics] listen = "127.0.0.1:9464"``).

One collector reads the bridge's own counters at scrape time: the engines'
stats, the adapters' per-node counters and reply times, the outbox and the
broker link. Nothing is counted twice and nothing runs between scrapes.
prometheus_client is imported only when ``[metrics]`` is configured.
"""
from __future__ import annotations

import errno
import logging
import os
import selectors
import socket
import threading
import time
from typing import Any, Dict, Iterator, List, Optional, Protocol

from ..errors import InvalidTypeError, InvalidValueError, PortError
from .buses import REPLY_BUCKETS
from .mqtt import MissingDependencyError


class MetricsSource(Protocol):
    """What the collector reads of a bridge (:class:`fap_py.bridge.Bridge` is one).
    A protocol, not an import of Bridge: bridge.py imports this module."""

    @property
    def buses(self) -> Any: ...
    @property
    def link(self) -> Any: ...
    @property
    def store(self) -> Any: ...
    @property
    def not_stored(self) -> Any: ...
    @property
    def tx_refused(self) -> Any: ...
    @property
    def duplicates(self) -> Any: ...

    def node_states(self) -> Any: ...


_SOURCE_ATTRS = ("buses", "link", "store", "not_stored", "tx_refused", "duplicates", "node_states")

log = logging.getLogger(__name__)

METRICS_HINT = "[metrics] needs prometheus_client: pip install 'fap_py[bridge]'"

# protocol-neutral bus metrics: the adapter's health counters (buses._HEALTH)
_NEUTRAL = ("crc_errors", "timeouts", "retries", "collisions")


class BridgeCollector:
    """A prometheus_client collector over one :class:`~fap_py.bridge.Bridge`."""

    def __init__(self, bridge: MetricsSource) -> None:
        self.bridge = bridge

    def describe(self) -> List[Any]:
        return []   # no fixed set: metrics follow the configured buses

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily

        b = self.bridge
        up = GaugeMetricFamily("fap_bridge_bus_up", "1 while the bus's port is open", labels=["bus", "protocol"])
        frames = CounterMetricFamily("fap_bridge_bus_frames", "frames on the bus (engine counters)",
                                     labels=["bus", "direction"])
        neutral = {name: CounterMetricFamily(f"fap_bridge_bus_{name}", f"{name.replace('_', ' ')} on the bus",
                                             labels=["bus"]) for name in _NEUTRAL}
        engine = CounterMetricFamily("fap_bridge_engine_events", "every engine counter, by its own name",
                                     labels=["bus", "counter"])
        events = CounterMetricFamily("fap_bridge_bus_events", "the bridge's counters per bus",
                                     labels=["bus", "event"])
        node_msgs = CounterMetricFamily("fap_bridge_node_messages", "messages from (rx) and to (tx) a node",
                                        labels=["bus", "node", "direction"])
        node_err = CounterMetricFamily("fap_bridge_node_errors", "failed requests to a node",
                                       labels=["bus", "node"])
        node_to = CounterMetricFamily("fap_bridge_node_timeouts", "requests a node did not answer",
                                      labels=["bus", "node"])
        node_reply = HistogramMetricFamily("fap_bridge_node_reply_seconds", "request to reply, per node",
                                           labels=["bus", "node"])
        node_active = GaugeMetricFamily("fap_bridge_node_active", "1 while the node is active",
                                        labels=["bus", "node"])
        for name, adapter in b.buses.items():
            proto = adapter.cfg.protocol
            up.add_metric([name, proto], 1.0 if adapter.open_error is None else 0.0)
            health = adapter.health_counters()
            for direction in ("rx", "tx"):
                if f"frames_{direction}" in health:
                    frames.add_metric([name, direction], health[f"frames_{direction}"])
            for metric in _NEUTRAL:
                if metric in health:
                    neutral[metric].add_metric([name], health[metric])
            for key, value in adapter.engine_stats().items():
                if isinstance(value, int) and not isinstance(value, bool):
                    engine.add_metric([name, key], value)
            for key, value in adapter.counters.items():
                events.add_metric([name, key], value)
            for node, c in sorted(adapter.nodes.items()):
                labels = [name, str(node)]
                node_msgs.add_metric(labels + ["rx"], c.rx)
                node_msgs.add_metric(labels + ["tx"], c.tx)
                node_err.add_metric(labels, c.errors)
                node_to.add_metric(labels, c.timeouts)
                if c.reply_count:
                    running, buckets = 0, []
                    for le, n in zip(REPLY_BUCKETS, c.buckets):
                        running += n
                        buckets.append((repr(le), running))
                    buckets.append(("+Inf", c.reply_count))
                    node_reply.add_metric(labels, buckets, c.reply_sum)
        for (bus, node), st in b.node_states().items():
            node_active.add_metric([bus, str(node)], 1.0 if st else 0.0)
        yield from (up, frames, *neutral.values(), engine, events, node_msgs, node_err, node_to, node_reply,
                    node_active)

        link = b.link
        yield GaugeMetricFamily("fap_bridge_outbox_rows", "publications waiting for the broker",
                                value=b.store.pending)
        yield CounterMetricFamily("fap_bridge_outbox_dropped", "oldest publications dropped at queue_max",
                                  value=b.store.dropped)
        yield CounterMetricFamily("fap_bridge_outbox_not_stored", "publications the outbox could not write",
                                  value=b.not_stored)
        yield GaugeMetricFamily("fap_bridge_mqtt_connected", "1 while connected to the broker",
                                value=1.0 if link.connected else 0.0)
        current = GaugeMetricFamily("fap_bridge_mqtt_broker", "1 for the broker in use (its place in the "
                                    "[[broker]] list, 0 preferred), 0 for the others", labels=["broker", "index"])
        for i, br in enumerate(getattr(link, "brokers", ())):
            current.add_metric([br.address, str(i)], 1.0 if i == getattr(link, "broker_index", 0) else 0.0)
        yield current
        yield CounterMetricFamily("fap_bridge_mqtt_switches", "moves from one broker of the list to another "
                                  "(failover and failback)", value=getattr(link, "switches", 0))
        yield CounterMetricFamily("fap_bridge_mqtt_fallbacks", "brokers that refused MQTT 5 (3.1.1 used)",
                                  value=getattr(link, "fallbacks", 0))
        yield CounterMetricFamily("fap_bridge_mqtt_stalls", "connections stuck (no PUBACK within ack_timeout, "
                                  "no CONNACK within connect_timeout), made anew", value=getattr(link, "stalls", 0))
        yield CounterMetricFamily("fap_bridge_mqtt_connects", "connections made", value=link.connects)
        yield CounterMetricFamily("fap_bridge_mqtt_disconnects", "connections lost", value=link.disconnects)
        yield CounterMetricFamily("fap_bridge_mqtt_published", "publications the broker acknowledged",
                                  value=link.published)
        refused = CounterMetricFamily("fap_bridge_mqtt_refused", "publications the broker refused (MQTT 5)",
                                      labels=["reason"])
        for reason, n in sorted(link.refused_pubs.items()):
            refused.add_metric([reason], n)
        yield refused
        own = CounterMetricFamily("fap_bridge_mqtt_own_refused",
                                  "the bridge's own publications (status, health, discovery) the broker "
                                  "refused", labels=["topic"])
        for topic, n in sorted(getattr(link, "refused_own", {}).items()):
            own.add_metric([topic], n)
        yield own
        find = getattr(b, "output", None)   # a BridgeView: the outputs by name
        sp = find("sparkplug") if callable(find) else getattr(b, "sparkplug", None)
        if sp is not None:
            yield CounterMetricFamily("fap_bridge_sparkplug_invalid_commands",
                                      "NCMD that were not a Sparkplug payload or asked nothing known",
                                      value=sp.invalid_commands)
            yield CounterMetricFamily("fap_bridge_sparkplug_rebirths_coalesced",
                                      "rebirth requests folded into another (rate limit)",
                                      value=sp.rebirths.coalesced)
            refused = CounterMetricFamily("fap_bridge_sparkplug_state_refused",
                                          "primary host STATE payloads refused (not JSON, wrong types, "
                                          "an old timestamp)", labels=["reason"])
            for reason, n in sorted(getattr(sp, "state_refused", {}).items()):
                refused.add_metric([reason], n)
            yield refused
            yield CounterMetricFamily("fap_bridge_sparkplug_held_dropped",
                                      "DDATA dropped from the full queue held while not born",
                                      value=getattr(sp, "queue_dropped", 0))
        yield CounterMetricFamily("fap_bridge_tx_refused", "malformed tx refused", value=b.tx_refused)
        yield CounterMetricFamily("fap_bridge_tx_duplicates", "tx redeliveries dropped", value=b.duplicates)


class SimCollector:
    """The counters of a ``fap sim`` running beside the bridge (``[metrics] sim_control``),
    read from its control socket at scrape time: per node requests, replies, errors,
    damaged requests and faults applied, per bus unmatched requests and reopens, and the
    sim's fault totals. ``fap_sim_up`` is 0 (and nothing else is exported) while the sim
    does not answer; the first failure of a run of them is logged."""

    def __init__(self, spec: str, timeout: float = 1.0) -> None:
        from ..sim._control import unix_path

        unix_path(spec)
        self.spec, self.timeout = spec, timeout
        self._failing = False

    def describe(self) -> List[Any]:
        return []

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        from ..errors import FapError
        from ..sim._control import counters

        try:
            st = counters(self.spec, self.timeout)
        except FapError as exc:
            if not self._failing:
                log.warning("metrics: the sim at %s does not answer: %s", self.spec, exc)
            self._failing = True
            yield GaugeMetricFamily("fap_sim_up", "1 while the sim's control socket answers", value=0.0)
            return
        if self._failing:
            log.info("metrics: the sim at %s answers again", self.spec)
        self._failing = False
        yield GaugeMetricFamily("fap_sim_up", "1 while the sim's control socket answers", value=1.0)
        node = ["bus", "protocol", "address"]
        per_node = {key: CounterMetricFamily(f"fap_sim_node_{key}", what, labels=node) for key, what in (
            ("requests", "requests the node served"), ("replies", "replies the node sent"),
            ("errors", "requests whose generator hook raised (no reply)"),
            ("requests_damaged", "requests a direction-request fault damaged (not executed)"))}
        faults = CounterMetricFamily("fap_sim_node_faults", "faults applied to the node's transactions",
                                     labels=node + ["kind"])
        unmatched = CounterMetricFamily("fap_sim_bus_unmatched", "requests for an address no node has",
                                        labels=["bus", "protocol"])
        reopened = CounterMetricFamily("fap_sim_bus_reopened", "times the bus's port was opened again",
                                       labels=["bus", "protocol"])
        for bus in st.get("buses", ()):
            labels = [str(bus["name"]), str(bus["protocol"])]
            unmatched.add_metric(labels, bus.get("unmatched", 0))
            reopened.add_metric(labels, bus.get("reopened", 0))
            for n in bus.get("nodes", ()):
                where = labels + [str(n["address"])]
                for key, family in per_node.items():
                    family.add_metric(where, n.get(key, 0))
                for kind, count in sorted(n.get("faults", {}).items()):
                    faults.add_metric(where + [kind], count)
        applied = CounterMetricFamily("fap_sim_faults_applied", "faults applied, by kind", labels=["kind"])
        for kind, count in sorted(st.get("faults_applied", {}).items()):
            applied.add_metric([kind], count)
        yield from (*per_node.values(), faults, unmatched, reopened, applied)
        yield GaugeMetricFamily("fap_sim_faults_active", "faults in the sim's table now",
                                value=len(st.get("faults", ())))
        yield CounterMetricFamily("fap_sim_fault_changes", "faults added, removed, switched",
                                  value=st.get("fault_changes", 0))


#: connections the endpoint serves at once; a new one past it closes the oldest
#: (the slowest: a scrape sends its request at once)
MAX_CLIENTS = 32
#: seconds a connection may take to send its request and read the answer
CLIENT_TIMEOUT = 5.0
_REQUEST_MAX = 8192   #: bytes of a request's head


class _Conn:
    __slots__ = ("sock", "inbuf", "out", "deadline")

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock = sock
        self.inbuf = b""
        self.out: Optional[memoryview] = None
        self.deadline = deadline


class MetricsServer:
    """The HTTP endpoint: one thread, one selector, at most :data:`MAX_CLIENTS`
    connections, each closed after :data:`CLIENT_TIMEOUT` seconds; a slow or hostile
    client costs one fd for a bounded time, never a thread, and never the bus side."""

    def __init__(self, bridge: MetricsSource, host: str, port: int, *, max_clients: int = MAX_CLIENTS,
                 timeout: float = CLIENT_TIMEOUT, sim_control: Optional[str] = None) -> None:
        if not all(hasattr(bridge, a) for a in _SOURCE_ATTRS) or not isinstance(host, str) \
                or isinstance(port, bool) \
                or not isinstance(port, int):
            raise InvalidTypeError("MetricsServer(bridge: Bridge, host: str, port: int)")
        if not 0 <= port <= 65535:
            raise InvalidValueError(f"port must be 0..65535, not {port!r:.40}")
        if isinstance(max_clients, bool) or not isinstance(max_clients, int) or not 1 <= max_clients <= 4096:
            raise InvalidValueError(f"max_clients must be 1..4096, not {max_clients!r:.40}")
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not 0 < timeout <= 3600:
            raise InvalidValueError(f"timeout must be 0 < s <= 3600, not {timeout!r:.40}")
        try:
            from prometheus_client import CollectorRegistry
            from prometheus_client.exposition import CONTENT_TYPE_LATEST, generate_latest
        except ImportError:
            raise MissingDependencyError(METRICS_HINT) from None
        self._generate, self._ctype = generate_latest, CONTENT_TYPE_LATEST
        self.max_clients, self.timeout = max_clients, float(timeout)
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(BridgeCollector(bridge))
        if sim_control is not None:     # a sim beside the bridge: its counters too
            self.registry.register(SimCollector(sim_control))
        try:
            infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
            family, _, _, _, addr = infos[0]
            self._sock = socket.socket(family, socket.SOCK_STREAM)
            try:
                self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                self._sock.bind(addr)
                self._sock.listen(64)
            except BaseException:
                self._sock.close()
                raise
        except OSError as exc:
            raise PortError(getattr(exc, "errno", None) or errno.EADDRNOTAVAIL,
                            f"metrics.listen {host}:{port}: {getattr(exc, 'strerror', None) or exc}") from None
        self._sock.setblocking(False)
        self.port = int(self._sock.getsockname()[1])
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._sock, selectors.EVENT_READ, None)
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        self._conns: Dict[int, _Conn] = {}     # fd -> connection, oldest first
        self.evicted = 0       #: connections closed to make room for a new one
        self.timed_out = 0     #: connections closed by CLIENT_TIMEOUT
        self.served = 0        #: answers sent
        self._closing = False
        self._thread = threading.Thread(target=self._serve, name="fap-bridge-metrics", daemon=True)
        self._thread.start()
        log.info("metrics on http://%s:%d/metrics", host, self.port)

    @property
    def clients(self) -> int:
        """Connections open now."""
        return len(self._conns)

    # -- the loop (its own thread) ----------------------------------------------------
    def _serve(self) -> None:
        while not self._closing:
            now = time.monotonic()
            wait = min([c.deadline for c in self._conns.values()], default=now + 1.0) - now
            for key, events in self._sel.select(max(0.0, min(wait, 1.0))):
                if key.data == "wake":
                    return
                if key.data is None:
                    self._accept()
                else:
                    self._io(key.data, events)
            now = time.monotonic()
            for c in [c for c in self._conns.values() if c.deadline <= now]:
                self.timed_out += 1
                self._drop(c)

    def _accept(self) -> None:
        for _ in range(64):   # what is waiting now, bounded per round
            try:
                sock, _ = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:   # EMFILE and friends: the listener stays, retried next round
                log.warning("metrics: accept: %s", exc.strerror or exc)
                return
            while len(self._conns) >= self.max_clients:
                self.evicted += 1
                self._drop(next(iter(self._conns.values())))
            sock.setblocking(False)
            c = _Conn(sock, time.monotonic() + self.timeout)
            self._conns[sock.fileno()] = c
            self._sel.register(sock, selectors.EVENT_READ, c)

    def _io(self, c: _Conn, events: int) -> None:
        try:
            if c.out is None:
                data = c.sock.recv(4096)
                if not data:
                    self._drop(c)
                    return
                c.inbuf += data
                if b"\r\n\r\n" not in c.inbuf and b"\n\n" not in c.inbuf:
                    if len(c.inbuf) > _REQUEST_MAX:
                        self._answer(c, 431, b"request too large\n")
                    return
                self._respond(c)
            if c.out is not None:
                n = c.sock.send(c.out)
                c.out = c.out[n:]
                if not c.out:
                    self.served += 1
                    self._drop(c)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(c)

    def _respond(self, c: _Conn) -> None:
        line = c.inbuf.split(b"\n", 1)[0].strip().split()
        if len(line) < 2 or line[0] not in (b"GET", b"HEAD"):
            self._answer(c, 405, b"only GET\n")
            return
        path = line[1].split(b"?", 1)[0]
        if path not in (b"/", b"/metrics"):
            self._answer(c, 404, b"not found: /metrics\n")
            return
        try:
            body = self._generate(self.registry)
        except Exception:   # a collector bug must not kill the endpoint
            log.exception("metrics: collect")
            self._answer(c, 500, b"collect failed\n")
            return
        self._answer(c, 200, b"" if line[0] == b"HEAD" else body, self._ctype, len(body))

    def _answer(self, c: _Conn, status: int, body: bytes, ctype: str = "text/plain; charset=utf-8",
                length: Optional[int] = None) -> None:
        reason = {200: "OK", 404: "Not Found", 405: "Method Not Allowed", 431: "Request Header Fields Too Large",
                  500: "Internal Server Error"}[status]
        head = (f"HTTP/1.1 {status} {reason}\r\nContent-Type: {ctype}\r\n"
                f"Content-Length: {len(body) if length is None else length}\r\nConnection: close\r\n\r\n")
        c.out = memoryview(head.encode() + body)
        self._sel.modify(c.sock, selectors.EVENT_WRITE, c)

    def _drop(self, c: _Conn) -> None:
        self._conns.pop(c.sock.fileno(), None)
        try:
            self._sel.unregister(c.sock)
        except (KeyError, ValueError):
            pass
        c.sock.close()

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        os.write(self._wake_w, b"x")
        self._thread.join(5.0)
        for c in list(self._conns.values()):
            self._drop(c)
        self._sel.close()
        self._sock.close()
        os.close(self._wake_r)
        os.close(self._wake_w)


__all__ = ["BridgeCollector", "CLIENT_TIMEOUT", "MAX_CLIENTS", "METRICS_HINT", "MetricsServer"]
