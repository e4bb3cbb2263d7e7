"""Sparkplug B (opt-in, ``[sparkplug]``): the bridge as one Sparkplug edge node, each node
of a bus with ``sparkplug = true`` one Sparkplug device.

Topics (Sparkplug B 3.0, namespace ``spBv1.0``)::

    spBv1.0/<group>/NBIRTH/<edge>           seq 0, bdSeq, "Node Control/Rebirth", the bridge's metrics
    spBv1.0/<group>/NDEATH/<edge>           the MQTT will (and sent before a clean stop): bdSeq
    spBv1.0/<group>/NDATA/<edge>            the bridge's metrics that changed (every stats_interval)
    spBv1.0/<group>/DBIRTH/<edge>/<bus>-<node>   when a node becomes active (and after every NBIRTH)
    spBv1.0/<group>/DDATA/<edge>/<bus>-<node>    each message received, counters, reply time
    spBv1.0/<group>/DDEATH/<edge>/<bus>-<node>   when a node becomes inactive
    spBv1.0/<group>/NCMD/<edge>             subscribed: "Node Control/Rebirth" = true -> births again

It runs its own MQTT connection (client id ``<client id>-spb``): Sparkplug
needs NDEATH as the will of a clean session, while the bridge's main
connection keeps ``status`` as its will and a persistent session. ``seq``
counts every message after NBIRTH modulo 256; ``bdSeq`` counts connections
modulo 256 and is the same in an NBIRTH and the NDEATH registered with it.
DDATA made while the connection is down wait in a bounded queue and are
sent after the next births, their metrics flagged ``is_historical``.

The payload is protobuf: the Sparkplug B ``Payload``/``Metric`` messages
(the fields the bridge writes, with the specification's field numbers)
are built as a descriptor at import, with the ``protobuf`` package and no
generated code, so any protobuf runtime >= 4.22 works; a decoder with the
full Eclipse Tahu schema reads them (the tests decode with it).
"""
from __future__ import annotations

import collections
import logging
import sys
import threading
import time
from typing import Any, Deque, Dict, List, Optional, Tuple

from .._validate import check_bool, check_seconds
from ..errors import InvalidTypeError, InvalidValueError
from .config import BridgeConfig, check_bus_node
from .mqtt import MissingDependencyError, describe_connect_error, paho

log = logging.getLogger(__name__)

SPARKPLUG_HINT = "[sparkplug] needs protobuf: pip install 'fap_py[bridge]'"
NAMESPACE = "spBv1.0"
REBIRTH = "Node Control/Rebirth"
#: seconds between two rebirths the host asks for (NCMD); more within them: one at their end
REBIRTH_MIN = 5.0
QUEUE_MAX = 10_000    # DDATA kept while disconnected (oldest dropped past it, counted)

# Sparkplug B DataType values (the specification's enumeration)
INT64, UINT64, DOUBLE, BOOLEAN, STRING, BYTES = 4, 8, 10, 11, 12, 17

# (name, number, label, type, type_name) of the fields written; protobuf FieldDescriptorProto codes
_OPT, _REP = 1, 3
_UINT64, _UINT32, _BOOL, _STRING, _BYTES, _DOUBLE, _FLOAT, _MESSAGE = 4, 13, 8, 9, 12, 1, 2, 11
_METRIC_FIELDS = (("name", 1, _OPT, _STRING), ("alias", 2, _OPT, _UINT64), ("timestamp", 3, _OPT, _UINT64),
                  ("datatype", 4, _OPT, _UINT32), ("is_historical", 5, _OPT, _BOOL),
                  ("is_transient", 6, _OPT, _BOOL), ("is_null", 7, _OPT, _BOOL),
                  ("int_value", 10, _OPT, _UINT32), ("long_value", 11, _OPT, _UINT64),
                  ("float_value", 12, _OPT, _FLOAT), ("double_value", 13, _OPT, _DOUBLE),
                  ("boolean_value", 14, _OPT, _BOOL), ("string_value", 15, _OPT, _STRING),
                  ("bytes_value", 16, _OPT, _BYTES))
_PAYLOAD_FIELDS = (("timestamp", 1, _OPT, _UINT64), ("seq", 3, _OPT, _UINT64), ("uuid", 4, _OPT, _STRING),
                   ("body", 5, _OPT, _BYTES))
_VALUE_FIELD = {INT64: "long_value", UINT64: "long_value", DOUBLE: "double_value", BOOLEAN: "boolean_value",
                STRING: "string_value", BYTES: "bytes_value"}

_payload_class: Any = None


def payload_class() -> Any:
    """The protobuf message class of a Sparkplug B Payload (built once, in a private pool)."""
    global _payload_class
    if _payload_class is not None:
        return _payload_class
    try:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    except ImportError:
        raise MissingDependencyError(SPARKPLUG_HINT) from None
    f = descriptor_pb2.FileDescriptorProto(name="fap_sparkplug_b.proto", package="org.eclipse.tahu.protobuf",
                                           syntax="proto2")
    payload = f.message_type.add(name="Payload")
    metric = payload.nested_type.add(name="Metric")
    for name, number, label, kind in _METRIC_FIELDS:
        metric.field.add(name=name, number=number, label=label, type=kind)
    for name, number, label, kind in _PAYLOAD_FIELDS:
        payload.field.add(name=name, number=number, label=label, type=kind)
    payload.field.add(name="metrics", number=2, label=_REP, type=_MESSAGE,
                      type_name=".org.eclipse.tahu.protobuf.Payload.Metric")
    pool = descriptor_pool.DescriptorPool()   # not the default pool: no clash with a Tahu module
    pool.Add(f)
    desc = pool.FindMessageTypeByName("org.eclipse.tahu.protobuf.Payload")
    get = getattr(message_factory, "GetMessageClass", None)
    _payload_class = get(desc) if get else message_factory.MessageFactory(pool).GetPrototype(desc)
    return _payload_class


Metric = Tuple[str, int, Any]   # name, datatype, value (None: is_null)


def encode(metrics: List[Metric], seq: Optional[int], ts_ms: Optional[int] = None,
           historical: bool = False) -> bytes:
    """A Sparkplug B payload; ``seq`` None for NDEATH (which has none)."""
    if seq is not None and (isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= 0xFF):
        raise InvalidValueError(f"seq must be 0..255 or None, not {seq!r:.40}")
    if not isinstance(metrics, (list, tuple)):
        raise InvalidTypeError(f"metrics must be a list of (name, datatype, value), not {type(metrics).__name__}")
    p = payload_class()()
    try:
        p.timestamp = int(time.time() * 1000) if ts_ms is None else ts_ms
        if seq is not None:
            p.seq = seq
        for name, datatype, value in metrics:
            if datatype not in _VALUE_FIELD:
                raise InvalidValueError(f"metric {name!r:.40}: datatype {datatype!r:.20} is not one the bridge writes")
            m = p.metrics.add(name=name, datatype=datatype, timestamp=p.timestamp)
            if historical:
                m.is_historical = True
            if value is None:
                m.is_null = True
            else:
                setattr(m, _VALUE_FIELD[datatype], value)
    except (TypeError, ValueError) as exc:   # protobuf's range and type checks
        if isinstance(exc, InvalidValueError):
            raise
        raise InvalidValueError(f"not a Sparkplug metric list: {str(exc)[:200]}") from None
    return bytes(p.SerializeToString())


class SparkplugNode:
    """The edge node: its own MQTT connection, births, deaths, data and rebirth commands."""

    def __init__(self, config: BridgeConfig, node_metrics: Any) -> None:
        if not isinstance(config, BridgeConfig) or config.sparkplug is None or not callable(node_metrics):
            raise InvalidTypeError("SparkplugNode(config: BridgeConfig with [sparkplug], node_metrics: callable)")
        payload_class()   # MissingDependencyError now, not at the first publication
        sp = config.sparkplug
        self.config = config
        self.group, self.edge = sp.group_id, sp.edge_node_id
        self.buses = {b.name for b in config.buses if b.sparkplug}
        self._node_metrics = node_metrics          # () -> [Metric]: the bridge's own counters
        self._lock = threading.RLock()
        self._seq = 0
        self.bd_seq = -1                           # incremented at each connect: 0 first
        self._devices: Dict[str, List[Metric]] = {}   # device id -> its latest metrics (alive ones)
        self._queue: Deque[Tuple[str, List[Metric], int]] = collections.deque()
        self._node_sent: Dict[str, Metric] = {}    # the node metrics as last sent
        self.queue_dropped = 0
        self.invalid_commands = 0                  # NCMD that are not a Sparkplug payload or ask nothing
        from .ratelimit import Coalescer

        self.rebirths = Coalescer(self._rebirth, REBIRTH_MIN, "Sparkplug rebirth")
        self._connected = False
        self.births = 0
        mqtt = paho()
        b = config.broker
        base_id = b.client_id or f"fap-bridge-{config.host}"
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"{base_id}-spb",
                                  clean_session=True, protocol=mqtt.MQTTv311)
        if b.username is not None:
            self.client.username_pw_set(b.username, b.password)
        if b.tls:
            self.client.tls_set(ca_certs=b.ca, certfile=b.cert, keyfile=b.key)
        self.client.reconnect_delay_set(b.reconnect_min, b.reconnect_max)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self.client.on_connect_fail = self._on_connect_fail
        self._next_will()

    # -- topics -----------------------------------------------------------------
    def topic(self, kind: str, device: Optional[str] = None) -> str:
        if not isinstance(kind, str) or not (device is None or isinstance(device, str)):
            raise InvalidTypeError("topic(kind: str, device: str or None)")
        t = f"{NAMESPACE}/{self.group}/{kind}/{self.edge}"
        return t if device is None else f"{t}/{device}"

    @staticmethod
    def device_id(bus: str, node: int) -> str:
        return f"{bus}-{node}"

    # -- lifetime -----------------------------------------------------------------
    def _next_will(self) -> None:
        """A new bdSeq, and the NDEATH carrying it as the will of the next connection."""
        self.bd_seq = (self.bd_seq + 1) % 256
        self.client.will_set(self.topic("NDEATH"), encode([("bdSeq", INT64, self.bd_seq)], None), qos=1)

    def start(self) -> None:
        b = self.config.broker
        self.client.connect_async(b.host, b.port, keepalive=b.keepalive)
        self.client.loop_start()

    def stop(self, timeout: float = 5.0) -> None:
        """NDEATH (the spec's clean goodbye), then disconnect."""
        timeout = check_seconds(timeout, "timeout")
        self.rebirths.close()
        if self._connected:
            info = self.client.publish(self.topic("NDEATH"), encode([("bdSeq", INT64, self.bd_seq)], None), qos=1)
            try:
                info.wait_for_publish(timeout)
            except (RuntimeError, ValueError):
                pass
            self.client.disconnect()
        self.client.loop_stop()

    # -- paho callbacks (network thread) ----------------------------------------------
    def _on_connect_fail(self, client: Any, userdata: Any) -> None:
        b = self.config.broker
        log.info("sparkplug: broker %s", describe_connect_error(sys.exc_info()[1], b.host, b.port))

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            log.error("sparkplug: broker refused the connection: %s", reason)
            return
        client.subscribe(self.topic("NCMD"), qos=1)
        with self._lock:
            self._connected = True
            self.birth()
            queued, self._queue = list(self._queue), collections.deque()
            for device, metrics, ts in queued:   # store and forward: after the births, flagged historical
                self._send("DDATA", device, metrics, ts_ms=ts, historical=True)

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        with self._lock:
            was, self._connected = self._connected, False
            if was:
                self._next_will()   # the reconnect announces a new bdSeq
        if was:
            log.warning("sparkplug: lost the broker (%s)", reason)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        try:
            p = payload_class().FromString(msg.payload)
        except Exception as exc:   # protobuf's DecodeError and friends: a bad NCMD is ignored
            self.invalid_commands += 1
            if self.invalid_commands <= 10 or self.invalid_commands % 1000 == 0:
                log.warning("sparkplug: NCMD not a Sparkplug payload: %s (%d invalid so far)",
                            str(exc)[:200], self.invalid_commands)
            return
        if any(m.name == REBIRTH and m.boolean_value for m in p.metrics):
            log.info("sparkplug: rebirth requested")
            self.rebirths.request()   # at most once per REBIRTH_MIN s (coalesced)
        else:
            self.invalid_commands += 1
            if self.invalid_commands <= 10 or self.invalid_commands % 1000 == 0:
                log.warning("sparkplug: NCMD with no command this edge node knows (%d invalid so far)",
                            self.invalid_commands)

    def _rebirth(self) -> None:
        with self._lock:
            if self._connected:
                self.birth()

    # -- publications ------------------------------------------------------------------
    def _send(self, kind: str, device: Optional[str], metrics: List[Metric], ts_ms: Optional[int] = None,
              historical: bool = False) -> None:
        """Under the lock, connected: one message with the next seq."""
        self._seq = (self._seq + 1) % 256
        self.client.publish(self.topic(kind, device), encode(metrics, self._seq, ts_ms, historical), qos=0)

    def birth(self) -> None:
        """NBIRTH (seq 0) and a DBIRTH for every live device."""
        with self._lock:
            self.births += 1
            self._seq = 0
            own = self._node_metrics()
            self._node_sent = {m[0]: m for m in own}
            metrics = [("bdSeq", INT64, self.bd_seq), (REBIRTH, BOOLEAN, False), *own]
            self.client.publish(self.topic("NBIRTH"), encode(metrics, 0), qos=0)
            for device, dev_metrics in self._devices.items():
                self._send("DBIRTH", device, dev_metrics)

    def device(self, bus: str, node: int, metrics: List[Metric], alive: Optional[bool] = None) -> None:
        """A node's news: ``alive`` True/False -> DBIRTH/DDEATH, else DDATA with ``metrics``."""
        check_bus_node(bus, node)
        if alive is not None:
            check_bool(alive, "alive")
        if not isinstance(metrics, list):
            raise InvalidTypeError(f"metrics must be a list, not {type(metrics).__name__}")
        if bus not in self.buses:
            return
        device = self.device_id(bus, node)
        with self._lock:
            known = self._devices.get(device)
            if alive is False:
                if known is None:
                    return
                del self._devices[device]
                if self._connected:
                    self._send("DDEATH", device, [])
                return
            merged = {m[0]: m for m in (known or [])}
            merged.update((m[0], m) for m in metrics)
            self._devices[device] = list(merged.values())
            if known is None:          # a new live device: its birth carries every metric
                if self._connected:
                    self._send("DBIRTH", device, self._devices[device])
                return
            if not metrics:
                return
            if self._connected:
                self._send("DDATA", device, metrics)
            else:
                if len(self._queue) >= QUEUE_MAX:
                    self._queue.popleft()
                    self.queue_dropped += 1
                self._queue.append((device, metrics, int(time.time() * 1000)))

    def node_data(self) -> None:
        """NDATA with the bridge's own metrics that changed since the last NBIRTH/NDATA."""
        with self._lock:
            if not self._connected:
                return
            now = {m[0]: m for m in self._node_metrics()}
            changed = [m for name, m in now.items() if self._node_sent.get(name) != m]
            if changed:
                self._node_sent.update((m[0], m) for m in changed)
                self._send("NDATA", None, changed)

    @property
    def connected(self) -> bool:
        return self._connected


__all__ = ["NAMESPACE", "REBIRTH", "SPARKPLUG_HINT", "SparkplugNode", "encode", "payload_class"]
