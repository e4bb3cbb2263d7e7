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
    spBv1.0/STATE/<primary_host_id>         subscribed with ``primary_host_id``: births wait for online

Primary host application (Sparkplug 3.0, ``[sparkplug] primary_host_id``): the
births wait until the host's retained STATE says ``{"online": true, "timestamp": t}``
(tck-id-message-flow-edge-node-birth-publish-phid-wait, -wait-id: the host id is the
topic's last level, -wait-online, -wait-timestamp: a STATE older than the last one
taken is refused). DDATA made meanwhile are held in the bounded queue below. A STATE
offline: NDEATH, disconnect, and the connection made again, waiting for online
(tck-id-message-flow-edge-node-birth-publish-phid-offline). A STATE that is not a JSON
object with a boolean ``online`` and an integer ``timestamp`` is refused and counted
(``state_refused``), never acted on.

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
import json
import logging
import sys
import threading
import time
from typing import Any, Deque, Dict, List, Optional, Tuple

from .._validate import check_bool, check_seconds
from ..errors import InvalidTypeError, InvalidValueError
from .config import BridgeConfig, BrokerConfig, check_bus_node
from .mqtt import MissingDependencyError, describe_connect_error, paho

log = logging.getLogger(__name__)

SPARKPLUG_HINT = "[sparkplug] needs protobuf: pip install 'fap_py[bridge]'"
NAMESPACE = "spBv1.0"
REBIRTH = "Node Control/Rebirth"
#: seconds between two rebirths the host asks for (NCMD); more within them: one at their end
REBIRTH_MIN = 5.0
QUEUE_MAX = 10_000    # DDATA kept while disconnected (oldest dropped past it, counted)
STATE_MAX = 1024      # bytes of a STATE payload: a longer one is refused unread

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
        self.primary = sp.primary_host_id
        self.state_topic = None if self.primary is None else f"{NAMESPACE}/STATE/{self.primary}"
        self.host_online = False                   # the primary host's last STATE taken said online
        self._host_ts: Optional[int] = None        # the timestamp of the last STATE taken
        self.state_refused: Dict[str, int] = {}    # reason -> STATE payloads refused
        self.host_offline = 0                      # STATE offline taken while born (sessions ended)
        self._session = False                      # the MQTT session is up (births may still wait)
        from .ratelimit import Coalescer

        self.rebirths = Coalescer(self._rebirth, REBIRTH_MIN, "Sparkplug rebirth")
        self._connected = False
        self.births = 0
        self.broker = config.broker                # the broker in use (follows the main link's)
        self._restarting = threading.Lock()
        self._stopped = False
        self.client = self._make_client(self.broker)
        self._next_will()

    def _make_client(self, b: Any) -> Any:
        mqtt = paho()
        base_id = b.client_id or f"fap-bridge-{self.config.host}"
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"{base_id}-spb",
                             clean_session=True, protocol=mqtt.MQTTv311)
        if b.username is not None:
            client.username_pw_set(b.username, b.password)
        if b.tls:
            client.tls_set(ca_certs=b.ca, certfile=b.cert, keyfile=b.key)
        client.reconnect_delay_set(b.reconnect_min, b.reconnect_max)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_message = self._on_message
        client.on_connect_fail = self._on_connect_fail
        return client

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
        b = self.broker
        self.client.connect_async(b.host, b.port, keepalive=b.keepalive)
        self.client.loop_start()

    def follow(self, broker: Any) -> None:
        """Use ``broker`` (the main link's, after a failover or failback): NDEATH on the old
        one if born there, then a new session there (births as at any connect)."""
        if not isinstance(broker, BrokerConfig):
            raise InvalidTypeError(f"broker must be a BrokerConfig, not {type(broker).__name__}")
        if broker is self.broker:
            return
        log.info("sparkplug: moving to broker %s", broker.address)
        self._restart(broker)

    def _restart(self, broker: Any = None) -> None:
        """End the session (NDEATH first if born) and start a new one, on ``broker`` or the
        same; in a thread of its own (never paho's: it stops paho's loop)."""
        def run() -> None:
            with self._restarting:
                if self._stopped:
                    return
                self._end_session()
                with self._lock:
                    if broker is not None:
                        self.broker = broker
                        self.client = self._make_client(broker)
                    self._next_will()
                b = self.broker
                self.client.connect_async(b.host, b.port, keepalive=b.keepalive)
                self.client.loop_start()

        threading.Thread(target=run, name="fap-bridge-spb-restart", daemon=True).start()

    def _end_session(self, timeout: float = 2.0) -> None:
        """NDEATH if born (the spec's clean goodbye), disconnect, stop paho's loop."""
        with self._lock:
            was, self._connected, self._session = self._connected, False, False
            client = self.client
        if was:
            info = client.publish(self.topic("NDEATH"), encode([("bdSeq", INT64, self.bd_seq)], None), qos=1)
            try:
                info.wait_for_publish(timeout)
            except (RuntimeError, ValueError):
                pass
        try:
            client.disconnect()
        except (OSError, ValueError):
            pass
        client.loop_stop()

    def stop(self, timeout: float = 5.0) -> None:
        """NDEATH (the spec's clean goodbye), then disconnect."""
        timeout = check_seconds(timeout, "timeout")
        self.rebirths.close()
        with self._restarting:
            self._stopped = True
            self._end_session(timeout)

    # -- paho callbacks (network thread) ----------------------------------------------
    def _on_connect_fail(self, client: Any, userdata: Any) -> None:
        b = self.broker
        log.info("sparkplug: broker %s", describe_connect_error(sys.exc_info()[1], b.host, b.port))

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            log.error("sparkplug: broker refused the connection: %s", reason)
            return
        if client is not self.client:
            return
        client.subscribe(self.topic("NCMD"), qos=1)
        with self._lock:
            self._session = True
            if self.state_topic is not None:
                # the births wait for the host's STATE (retained: it comes with the subscription)
                self.host_online = False
                client.subscribe(self.state_topic, qos=1)
                log.info("sparkplug: waiting for the primary host %s to be online (%s)", self.primary,
                         self.state_topic)
                return
            self._go_live()

    def _go_live(self) -> None:
        """Under the lock, in session: NBIRTH, DBIRTHs, then the data held, in order."""
        self._connected = True
        self.birth()
        queued, self._queue = list(self._queue), collections.deque()
        for device, metrics, ts in queued:   # store and forward: after the births, flagged historical
            self._send("DDATA", device, metrics, ts_ms=ts, historical=True)

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if client is not self.client:
            return
        with self._lock:
            was, self._connected, self._session = self._connected, False, False
            if was:
                self._next_will()   # the reconnect announces a new bdSeq
        if was:
            log.warning("sparkplug: lost the broker (%s)", reason)

    def _refuse_state(self, why: str) -> None:
        """Under the lock: a STATE payload refused (counted by reason, logged bounded)."""
        self.state_refused[why] = self.state_refused.get(why, 0) + 1
        n = sum(self.state_refused.values())
        if n <= 10 or n % 1000 == 0:
            log.warning("sparkplug: STATE of primary host %s refused: %s (%d refused so far)",
                        self.primary, why, n)

    def _parse_state(self, payload: bytes) -> Optional[Tuple[bool, int]]:
        """Under the lock: (online, timestamp) of a STATE payload, or None (refused, counted)."""
        if len(payload) > STATE_MAX:
            self._refuse_state(f"payload of more than {STATE_MAX} bytes")
            return None
        try:
            doc = json.loads(payload)
        except (UnicodeDecodeError, ValueError, RecursionError):
            self._refuse_state("not JSON")
            return None
        if not isinstance(doc, dict):
            self._refuse_state("not a JSON object")
            return None
        online, ts = doc.get("online"), doc.get("timestamp")
        if not isinstance(online, bool):
            self._refuse_state("online is not a boolean")
            return None
        if isinstance(ts, bool) or not isinstance(ts, int) or not 0 <= ts < 1 << 63:
            self._refuse_state("timestamp is not an integer of ms since the epoch")
            return None
        if self._host_ts is not None and ts < self._host_ts:
            self._refuse_state("timestamp older than the last STATE taken")
            return None
        return online, ts

    def _on_state(self, payload: bytes) -> None:
        with self._lock:
            parsed = self._parse_state(payload)
            if parsed is None:
                return
            online, self._host_ts = parsed
            was = self.host_online
            self.host_online = online
            if online and self._session and not self._connected:
                log.info("sparkplug: primary host %s online: births", self.primary)
                self._go_live()
                return
            if online or not self._connected:
                if was and not online:
                    log.info("sparkplug: primary host %s offline (not born: data held)", self.primary)
                return
            self.host_offline += 1
        log.warning("sparkplug: primary host %s offline: NDEATH, and a new session that waits for it",
                    self.primary)
        self._restart()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        if client is not self.client:
            return
        if self.state_topic is not None and msg.topic == self.state_topic:
            self._on_state(msg.payload)
            return
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
