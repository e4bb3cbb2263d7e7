"""Prometheus metrics of the bridge (``[metrics] listen = "127.0.0.1:9464"``).

One collector reads the bridge's own counters at scrape time: the engines'
stats, the adapters' per-node counters and reply times, the outbox and the
broker link. Nothing is counted twice and nothing runs between scrapes.
prometheus_client is imported only when ``[metrics]`` is configured.
"""
from __future__ import annotations

import errno
import logging
import threading
from typing import Any, Iterator, List, Protocol

from ..errors import InvalidTypeError, InvalidValueError, PortError
from .buses import REPLY_BUCKETS
from .mqtt import MissingDependencyError


class MetricsSource(Protocol):
    """What the collector reads of a bridge (:class:`fap_py.bridge.Bridge` is one).
    A protocol, not an import of Bridge: bridge.py imports this module."""

    buses: Any
    link: Any
    store: Any
    not_stored: Any
    tx_refused: Any
    duplicates: Any

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
        yield CounterMetricFamily("fap_bridge_mqtt_connects", "connections made", value=link.connects)
        yield CounterMetricFamily("fap_bridge_mqtt_disconnects", "connections lost", value=link.disconnects)
        yield CounterMetricFamily("fap_bridge_mqtt_published", "publications the broker acknowledged",
                                  value=link.published)
        refused = CounterMetricFamily("fap_bridge_mqtt_refused", "publications the broker refused (MQTT 5)",
                                      labels=["reason"])
        for reason, n in sorted(link.refused_pubs.items()):
            refused.add_metric([reason], n)
        yield refused
        yield CounterMetricFamily("fap_bridge_tx_refused", "malformed tx refused", value=b.tx_refused)
        yield CounterMetricFamily("fap_bridge_tx_duplicates", "tx redeliveries dropped", value=b.duplicates)


class MetricsServer:
    """The HTTP endpoint (prometheus_client's server on its own registry)."""

    def __init__(self, bridge: MetricsSource, host: str, port: int) -> None:
        if not all(hasattr(bridge, a) for a in _SOURCE_ATTRS) or not isinstance(host, str) \
                or isinstance(port, bool) \
                or not isinstance(port, int):
            raise InvalidTypeError("MetricsServer(bridge: Bridge, host: str, port: int)")
        if not 0 <= port <= 65535:
            raise InvalidValueError(f"port must be 0..65535, not {port!r:.40}")
        try:
            from prometheus_client import CollectorRegistry, start_http_server
        except ImportError:
            raise MissingDependencyError(METRICS_HINT) from None
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(BridgeCollector(bridge))
        try:
            self._server, self._thread = start_http_server(port, addr=host, registry=self.registry)
        except OSError as exc:
            raise PortError(exc.errno or errno.EADDRNOTAVAIL,
                            f"metrics.listen {host}:{port}: {exc.strerror or exc}") from None
        self.port = int(self._server.server_address[1])
        log.info("metrics on http://%s:%d/metrics", host, self.port)

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        if isinstance(self._thread, threading.Thread):
            self._thread.join(5.0)


__all__ = ["BridgeCollector", "METRICS_HINT", "MetricsServer"]
