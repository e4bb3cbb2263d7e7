"""The broker side of the bridge: one paho-mqtt client and the outbox pump.

A fleet (docs/bridge.md, "Fleet"): ``config.brokers`` is an ordered list; one paho client
at a time, made for the broker in use (its own TLS, login, MQTT version). The fleet
thread moves to the next broker after ``failover.attempts`` failed attempts, makes a
3.1.1 client for a broker that refuses MQTT 5 (``protocol = "auto"``), probes the
earlier brokers every ``failover.failback_interval`` s and goes back to the first that
answers, and makes a stuck connection anew (no PUBACK within ``ack_timeout`` with rows
in flight, no CONNACK within ``connect_timeout``). Callbacks of a client left behind are
ignored (:meth:`MqttLink._stale`); the outbox is the one queue across brokers: the rows
in flight at a move are handed again at the next CONNACK, as after any reconnect.

paho-mqtt is imported here only, and lazily (:func:`paho`), so ``fap
--help`` and everything else in fap_py works without the ``bridge`` extra.

Delivery bus -> broker: every publication is first a row of the on-disk
outbox (:class:`~fap_py.bridge.store.Store`); the pump hands rows to paho in
sequence order, at most ``inflight`` unacknowledged at a time, only while
connected, and deletes a row when its PUBACK arrives. Rows paho had sent
when the connection dropped are taken back from paho at the reconnect's
CONNACK and handed again by the pump, in sequence order, before any newer row
(after the bridge's own publications of the connect, below): order holds
across outages, and a repeat keeps its ``seq``.

Probing: a broker may close the connection instead of (or right after)
refusing a publication; mosquitto 2.0 does so for an ACL denial, and the
PUBACKs it had queued for the rows before it are lost with the socket.
paho then re-sends the same rows in one burst at every reconnect and the
bridge never gets past them. After :data:`PROBE_AFTER` losses in a row with
rows in flight and no PUBACK between them, the pump takes those rows back
from paho and sends them one at a time; a row that is alone in flight when
the connection drops :data:`PROBE_STRIKES` times is counted as refused
(reason :data:`DROPPED_REASON`), logged, and leaves the outbox like any
refused row. Probing ends once every row that was in flight is settled
(taking rows back at every CONNACK, below, keeps paho from bursting them).

Acknowledgements are matched by paho's message id (mid), which wraps at 65,535 and
is shared by the outbox rows and the bridge's own publications (status, health,
Home Assistant discovery). A mid is tied to what it was sent for when
``publish()`` returns; a PUBACK that arrives before that is held only while a
publication is being handed to paho (:attr:`MqttLink._early`, emptied when no
publish call is running), so a PUBACK is never kept to be matched with a later
publication that reuses its mid.

The bridge's own publications (status, health, Home Assistant discovery) are
not outbox rows, and a refusal of one (an ACL that predates the health topic)
must never be blamed on a row. After each CONNACK the pump hands no row until
the own publications of the connect (status ``online``, health, discovery)
have been answered, sent one at a time (at most :data:`GATE_TIMEOUT` s): the
rows paho had in flight are taken back and handed again, in order, after them.
So a connection lost in that phase is the fault of the one own publication
then unanswered, and a loss while any own publication is unanswered never
counts towards probing the rows. A refusal (MQTT 5 PUBACK >= 0x80), or
:data:`PROBE_STRIKES` losses in a row with the same kind unanswered (mosquitto
2.0 closes the connection after a refusal and its PUBACK may be lost with the
socket), is counted under its topic (:attr:`MqttLink.refused_own`), logged,
and holds that kind (status, health, discovery) back for
:data:`OWN_BACKOFF_MIN` seconds, doubling at each new refusal up to
:data:`OWN_BACKOFF_MAX`: a few reconnects, not a storm.
"""
from __future__ import annotations

import collections
import logging
import socket
import ssl
import sys
import threading
import time
from typing import Any, Callable, Deque, Dict, List, Optional, Tuple

from .._validate import check_bool, check_bytes, check_int, check_seconds, check_timeout
from ..errors import FapError, InvalidTypeError
from .config import BridgeConfig
from .store import Store, StoreError

log = logging.getLogger(__name__)

INSTALL_HINT = "fap bridge needs paho-mqtt 2.x: pip install 'fap_py[bridge]'"


class MissingDependencyError(FapError):
    """paho-mqtt (the ``bridge`` extra) is not installed."""


class BrokerRefusedError(FapError):
    """The broker refused the bridge's credentials; retrying cannot help."""


def paho() -> Any:
    """The ``paho.mqtt.client`` module, or :class:`MissingDependencyError`."""
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        raise MissingDependencyError(INSTALL_HINT) from None
    if not hasattr(mqtt, "CallbackAPIVersion"):
        raise MissingDependencyError(INSTALL_HINT + " (found paho-mqtt 1.x)")
    return mqtt


# CONNACK codes that no retry can fix: bad credentials, not authorised, banned.
_FATAL_CONNACK = {4, 5, 134, 135, 138, 140}
# CONNACK codes of a broker that does not speak MQTT 5 (3.1.1's 1, as paho reads it: 132)
_NO_MQTT5 = {1, 132}

_PAYLOAD_MAX = 268_435_455   #: MQTT's largest packet (its remaining length field)
_LOG_FIRST = 10   # refused publications logged one by one; after that every 1000th
#: seconds the pump waits for a batch (a quarter of the in-flight window) before a round
#: with less: under load one disk transaction and one read per batch, never per message;
#: a lone publication goes at once (an empty window is always worth a round)
PUMP_LINGER = 0.005
#: losses of the connection in a row, each with rows in flight and no PUBACK between
#: them, before the pump probes (sends one row at a time)
PROBE_AFTER = 2
#: losses of the connection while one row was alone in flight before that row counts as
#: refused: a network outage rarely hits the same lone row three times in a row
PROBE_STRIKES = 3
#: the ``broker.refused`` key of a row the broker never acknowledged but always dropped
#: the connection on
DROPPED_REASON = "Connection closed on this publication"
#: seconds a kind of the bridge's own publications (status, health, discovery) is held
#: back after the broker refused one; doubled at each refusal up to OWN_BACKOFF_MAX
OWN_BACKOFF_MIN = 60.0
OWN_BACKOFF_MAX = 3600.0
#: seconds after a CONNACK the rows wait at most for the own publications of the connect
GATE_TIMEOUT = 1.0
#: seconds between two looks of the fleet thread's watchdog (no PUBACK, no CONNACK)
STALL_TICK = 0.25


class _Dropped:
    """The reason given to a row counted as refused by probing (no PUBACK came)."""
    is_failure = True

    def __str__(self) -> str:
        return DROPPED_REASON


def describe_connect_error(exc: Optional[BaseException], host: str, port: int) -> str:
    """One line naming why a connection attempt failed (TLS, refused, DNS, timeout ...)."""
    if not isinstance(host, str):
        raise InvalidTypeError(f"host must be a str, not {type(host).__name__}")
    check_int(port, "port", 0, 65535)
    if exc is not None and not isinstance(exc, BaseException):
        raise InvalidTypeError(f"exc must be an exception or None, not {type(exc).__name__}")
    where = f"{host}:{port}"
    if exc is None:
        return f"{where}: connection failed"
    if isinstance(exc, ssl.SSLCertVerificationError):
        return f"{where}: TLS certificate verification failed: {exc.verify_message or exc.reason}"
    if isinstance(exc, ssl.SSLError):
        return f"{where}: TLS error: {exc.reason or exc}"
    if isinstance(exc, ConnectionRefusedError):
        return f"{where}: connection refused (no broker listening)"
    if isinstance(exc, socket.gaierror):
        return f"{where}: DNS: cannot resolve {host!r}: {exc.strerror or exc}"
    if isinstance(exc, (socket.timeout, TimeoutError)):
        return f"{where}: timed out"
    if isinstance(exc, OSError) and exc.strerror:
        return f"{where}: {exc.strerror}"
    return f"{where}: {type(exc).__name__}: {exc}"


class MqttLink:
    """The broker connection: connect with backoff, the status topic, the
    tx subscription and the outbox pump.

    Args:
        config: the bridge configuration.
        store: the outbox.
        on_tx: called as ``on_tx(topic, payload)`` for every message on a
            tx topic (in paho's network thread: must not block).
    """

    def __init__(self, config: BridgeConfig, store: Store,
                 on_tx: Callable[[str, bytes, Optional[float]], None]) -> None:
        if not isinstance(config, BridgeConfig) or not isinstance(store, Store) or not callable(on_tx):
            raise InvalidTypeError("MqttLink(config: BridgeConfig, store: Store, on_tx: callable)")
        mqtt = paho()
        self._mqtt = mqtt
        self.config = config
        self.store = store
        self._on_tx = on_tx
        from paho.mqtt.packettypes import PacketTypes
        from paho.mqtt.properties import Properties

        self._props = (Properties, PacketTypes)
        self.status_topic = f"{config.prefix}/bridge/{config.host}/status"
        self.tx_filters = [f"{config.prefix}/{bus.name}/+/tx" for bus in config.buses]
        self.health_topic = f"{config.prefix}/bridge/{config.host}/health"
        #: the brokers, in order of preference (docs/bridge.md, "Fleet")
        self.brokers = config.brokers
        self._index = 0                           # the broker in use (or being tried)
        # MQTT 5 per broker: "auto" starts with 5 and falls back to 3.1.1 on a refusal
        self._v5 = [b.protocol != "3.1.1" for b in self.brokers]
        self._bad: Dict[int, str] = {}            # broker index -> why it refused us for good
        self._want: Optional[Tuple[str, int]] = None   # for the fleet thread: ("switch"|"fallback", index)
        self._draining = False                    # a failback waits for the rows in flight
        self._answered_no = False                 # the last CONNACK refused us (counted once)
        self.switches = 0                         # moves from one broker of the list to another
        self.fallbacks = 0                        # brokers that refused MQTT 5 (3.1.1 used)
        self.probes = 0                           # failback probes of an earlier broker
        self.stalls = 0                           # connections stuck (no PUBACK / CONNACK): made anew
        self._acked_at = time.monotonic()         # the last PUBACK of a row (or start of the window)
        self._connecting_since: Optional[float] = None   # TCP up, CONNACK awaited since
        self.v5 = self._v5[0]
        self.client = self._make_client(0)
        self._fleet_thread: Optional[threading.Thread] = None
        self._cond = threading.Condition()
        self._connected = False
        self._subscribed = False    # the broker confirmed the tx subscription
        self._stopping = False
        self.refused: Optional[str] = None
        self.connects = 0
        self.disconnects = 0
        self.published = 0
        self.refused_pubs: Dict[str, int] = {}   # PUBACK reason -> publications the broker refused
        self.last_error: Optional[str] = None    # why the last connection attempt failed
        self._failures = 0                       # failed attempts since the last success
        self.on_connected: Optional[Callable[[], None]] = None   # after each (re)connect
        self.extra: Dict[str, Callable[[bytes], None]] = {}    # more topics to subscribe: topic -> handler
        self._inflight: Dict[int, Tuple[int, str]] = {}   # paho mid -> outbox seq, topic
        self._own: Dict[int, str] = {}            # paho mid -> topic of the bridge's own publication
        self._early: Dict[int, Any] = {}          # mid -> reason, acknowledged before publish() returned
        self._publishing = 0                      # publish() calls running (while >0, _early may fill)
        self.refused_own: Dict[str, int] = {}     # topic -> own publications the broker refused
        self._held: Dict[str, Tuple[float, float]] = {}   # kind -> (monotonic until, backoff)
        self._own_strikes: Dict[str, int] = {}    # kind -> losses in a row with it unanswered
        self._gate_open = False                   # rows may be handed (the connect's own ones answered)
        self._gate_deadline = 0.0                 # monotonic: the gate opens then whatever happened
        self._own_queue: Deque[Tuple[str, bytes, bool]] = collections.deque()   # waiting for the gate
        self._own_current: Optional[int] = None   # the gate's own publication in flight (mid; -1: sending)
        self.own_backoff = (OWN_BACKOFF_MIN, OWN_BACKOFF_MAX)
        self._acked: List[int] = []           # seqs to delete
        self._last_handed = 0                 # highest seq handed to paho
        self._handed_gen = 0                  # bumped when probing lowers _last_handed
        self._batch = max(1, config.inflight // 4)   # rows per pump round under load
        self._lost_in_flight = 0              # losses in a row with rows in flight, no PUBACK since
        self._probe_until = 0                 # probing while a row up to this seq is unsettled
        self._strikes: Dict[int, int] = {}    # seq -> losses while it was alone in flight
        self._take_back_mids: List[int] = []  # paho mids to drop from paho's session at CONNACK
        self._pump_thread: Optional[threading.Thread] = None

    def _client_id(self, b: Any) -> str:
        return b.client_id or f"fap-bridge-{self.config.host}"

    def _make_client(self, index: int, probe: bool = False) -> Any:
        """A paho client for broker ``index`` of the list, with its own TLS and credentials;
        ``probe``: a throwaway one (clean session, no will, its own client id) that only
        asks whether the broker answers."""
        mqtt, b = self._mqtt, self.brokers[index]
        client_id = self._client_id(b) + ("-probe" if probe else "")
        # A persistent session: tx published while the bridge is away wait at the broker
        # (MQTT 5: clean start off and a session expiry; 3.1.1: clean session off).
        if self._v5[index]:
            client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5)
        else:
            client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id,
                                 clean_session=probe, protocol=mqtt.MQTTv311)
        client.connect_timeout = b.connect_timeout
        if b.username is not None:
            client.username_pw_set(b.username, b.password)
        if b.tls:
            client.tls_set(ca_certs=b.ca, certfile=b.cert, keyfile=b.key)
        if probe:
            return client
        # paho's own messages at debug: it logs every failed reconnect attempt as an error,
        # and the outage is already reported once by _on_disconnect
        if log.isEnabledFor(logging.DEBUG):   # paho formats a line per packet for on_log
            client.on_log = lambda c, u, level, buf: log.debug("paho: %s", buf)
        client.will_set(self.status_topic, b"offline", qos=1, retain=True)
        client.reconnect_delay_set(b.reconnect_min, b.reconnect_max)
        client.max_inflight_messages_set(self.config.inflight)
        client.on_connect = self._on_connect
        client.on_disconnect = self._on_disconnect
        client.on_publish = self._on_publish
        client.on_message = self._on_message
        client.on_subscribe = self._on_subscribe
        client.on_connect_fail = self._on_connect_fail
        return client

    def _connect_props(self, index: int) -> Dict[str, Any]:
        """connect_async's keywords for broker ``index``."""
        b = self.brokers[index]
        if not self._v5[index]:
            return {"keepalive": b.keepalive}
        props = self._props[0](self._props[1].CONNECT)
        props.SessionExpiryInterval = b.session_expiry
        return {"keepalive": b.keepalive, "clean_start": False, "properties": props}

    @property
    def broker(self) -> Any:
        """The broker in use, or being tried (a :class:`~fap_py.bridge.config.BrokerConfig`)."""
        return self.brokers[self._index]

    @property
    def broker_index(self) -> int:
        """Its place in the list (0: the preferred one)."""
        return self._index

    # -- lifetime ---------------------------------------------------------------
    def start(self) -> None:
        """Connect in the background (paho retries with backoff) and start the pump."""
        b = self.broker
        self.client.connect_async(b.host, b.port, **self._connect_props(self._index))
        self.client.loop_start()
        self._pump_thread = threading.Thread(target=self._pump, name="fap-bridge-pump", daemon=True)
        self._pump_thread.start()
        self._fleet_thread = threading.Thread(target=self._fleet, name="fap-bridge-fleet", daemon=True)
        self._fleet_thread.start()

    # -- the fleet: failover, fallback to 3.1.1, failback -------------------------
    def _fleet(self) -> None:
        """Moves between the brokers of the list: to the next one after ``failover.attempts``
        failed attempts on one, to 3.1.1 on a broker that refused MQTT 5, and back to an
        earlier (preferred) one when a probe finds it answering (``failover.failback``)."""
        fo = self.config.failover
        next_probe = time.monotonic() + fo.failback_interval
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._stopping or self._want is not None,
                                    max(0.0, min(next_probe - time.monotonic(), STALL_TICK)))
                if self._stopping:
                    return
            stall = self._stalled()
            if stall is not None:   # counted as a failed attempt: with a list, may move on
                self._failed(stall)
            with self._cond:
                if stall is not None and self._want is None:
                    self._want = ("reconnect", self._index)   # the same broker, a new connection
                want, self._want = self._want, None
                probe = (want is None and fo.failback and self._connected and self._index > 0
                         and time.monotonic() >= next_probe)
            if want is not None:
                self._switch(want[1], {"fallback": "fallback", "reconnect": "reconnect"}.get(want[0], "failover"))
                next_probe = time.monotonic() + fo.failback_interval
                continue
            if time.monotonic() >= next_probe:
                next_probe = time.monotonic() + fo.failback_interval
            if probe:
                for j in range(self._index):
                    if j not in self._bad and self._probe(j):
                        self._failback(j)
                        break

    def _stalled(self) -> Optional[str]:
        """Why the connection is stuck, or None: connected with rows in flight and no PUBACK for
        the broker's ``ack_timeout`` (a half-open link, a broker that stopped answering), or a
        TCP connection up and no CONNACK within its ``connect_timeout``. MQTT re-sends only on
        a new connection: the watchdog of the fleet thread makes one."""
        b, now = self.broker, time.monotonic()
        with self._cond:
            if self.refused is not None:
                return None
            if self._connected:
                self._connecting_since = None
                if self._inflight and now - self._acked_at > b.ack_timeout:
                    self._acked_at = now
                    self.stalls += 1
                    return (f"{b.address}: no acknowledgement for {b.ack_timeout:g} s with "
                            f"{len(self._inflight)} rows in flight (a new connection)")
                return None
            if self.client.socket() is None:
                self._connecting_since = None
                return None
            if self._connecting_since is None:
                self._connecting_since = now
            elif now - self._connecting_since > b.connect_timeout:
                self._connecting_since = None
                self.stalls += 1
                return f"{b.address}: no CONNACK within {b.connect_timeout:g} s (a new connection)"
        return None

    def _next_index(self) -> int:
        """Under ``_cond``: the broker after the current one (cycling), skipping refusals."""
        n = len(self.brokers)
        for step in range(1, n + 1):
            j = (self._index + step) % n
            if j not in self._bad:
                return j
        return self._index

    def _probe(self, index: int) -> bool:
        """Broker ``index`` answers a CONNECT with a CONNACK that accepts us (bounded by its
        ``connect_timeout``); a throwaway session, closed at once."""
        b = self.brokers[index]
        self.probes += 1
        answer: List[Any] = []
        client = self._make_client(index, probe=True)
        client.on_connect = lambda c, u, f, reason, p: answer.append(reason)
        deadline = time.monotonic() + b.connect_timeout
        try:
            client.connect(b.host, b.port, keepalive=max(5, b.keepalive))
            while not answer and time.monotonic() < deadline and not self._stopping:
                if client.loop(0.05) != self._mqtt.MQTT_ERR_SUCCESS:
                    break
        except (OSError, ValueError) as exc:
            log.debug("failback probe of %s: %s", b.address, describe_connect_error(exc, b.host, b.port))
            return False
        finally:
            try:
                client.disconnect()
            except (OSError, ValueError):
                pass
            sock = client.socket()
            if sock is not None:
                sock.close()
        ok = bool(answer) and not answer[0].is_failure
        if (answer and getattr(answer[0], "value", None) in _NO_MQTT5 and self._v5[index]
                and b.protocol == "auto"):
            self._v5[index] = False   # a 3.1.1 broker: probed (and used) with 3.1.1
            self.fallbacks += 1
            return self._probe(index)
        log.info("failback probe of %s (broker %d of %d): %s", b.address, index + 1, len(self.brokers),
                 "answers" if ok else (answer[0] if answer else "no answer"))
        return ok

    def _failback(self, index: int) -> None:
        """Back to the earlier broker ``index``: the rows in flight answered first (at most
        ``failover.drain`` s: the rest are handed again there, as after any loss)."""
        with self._cond:
            self._draining = True
            self._cond.wait_for(lambda: not self._inflight or not self._connected or self._stopping,
                                self.config.failover.drain)
        self._switch(index, "failback")

    def _switch(self, index: int, why: str) -> None:
        """Leave the current broker for broker ``index`` (or the same one, for 3.1.1 after a
        refusal of MQTT 5): a new paho client; the old one's callbacks are ignored from now on.
        The outbox is the one queue: the rows the old broker had not acknowledged are handed
        again, in order, at the new CONNACK (as after any reconnect)."""
        if why == "fallback":
            self._v5[index] = False
        new = self._make_client(index)
        with self._cond:
            if self._stopping:
                return
            old, old_index = self.client, self._index
            was = self._connected
            self._connected = self._subscribed = False
            self._gate_open = False
            self._own_queue.clear()
            self._own_current = None
            self._draining = False
            self._answered_no = False
            self._index = index
            self.client = new
            self.v5 = self._v5[index]
            self._connecting_since = None
            if was:
                self.disconnects += 1
            if index != old_index:   # a new broker: its own count of failed attempts
                self._failures = 0
                self.switches += 1
            self._cond.notify_all()
        old_b, b = self.brokers[old_index], self.brokers[index]
        if why == "fallback":
            log.warning("broker %s refuses MQTT 5: using MQTT 3.1.1 with it", b.address)
        elif why == "reconnect":
            log.info("broker %s: a new connection", b.address)
        else:
            log.warning("broker %s: %s (broker %d of %d%s) -> %s (broker %d of %d)", why,
                        old_b.address, old_index + 1, len(self.brokers), "" if was else ", not connected",
                        b.address, index + 1, len(self.brokers))
        try:
            old.disconnect()
        except (OSError, ValueError):
            pass
        old.loop_stop()
        new.connect_async(b.host, b.port, **self._connect_props(index))
        new.loop_start()

    def wait_connected(self, timeout: Optional[float]) -> bool:
        """True once connected and subscribed to the tx topics; raises
        BrokerRefusedError if the broker said no."""
        timeout = check_timeout(timeout)
        with self._cond:
            self._cond.wait_for(lambda: self._subscribed or self.refused is not None, timeout)
            if self.refused is not None:
                raise BrokerRefusedError(self.refused)
            return self._subscribed

    @property
    def connected(self) -> bool:
        return self._connected

    def alive(self) -> bool:
        """The outbox pump runs."""
        return self._pump_thread is not None and self._pump_thread.is_alive()

    @property
    def refused_total(self) -> int:
        """Publications the broker refused (MQTT 5 PUBACK reason code >= 0x80)."""
        return sum(self.refused_pubs.values())

    def publish_now(self, topic: str, payload: bytes, retain: bool = True) -> bool:
        """Publish outside the outbox (QoS 1, best effort): the bridge's own health, which
        must get out even when the outbox cannot be written. True if handed to paho (or
        queued for the connect phase); False if not connected, held back after a refusal,
        or refused by paho: the caller publishes it again later (every connect does)."""
        if not isinstance(topic, str):
            raise InvalidTypeError(f"topic must be a str, not {type(topic).__name__}")
        payload = check_bytes(payload, "payload", 0, _PAYLOAD_MAX)
        check_bool(retain, "retain")
        with self._cond:
            if not self._connected or self._held_locked(topic):
                return False          # not queued either: a held topic waits for its caller
            if not self._gate_open:   # the connect phase: one at a time, after the others
                self._own_queue.append((topic, payload, retain))
                queued = True
            else:
                queued = False
        if queued:
            self._gate_next()
            return True
        return self._send_own(topic, payload, retain, handed=True)

    def _kind(self, topic: str) -> str:
        """What a refusal of ``topic`` holds back: the status or health topic itself, or
        every topic under the same first level (all of Home Assistant's discovery)."""
        if topic in (self.status_topic, self.health_topic):
            return topic
        return topic.split("/", 1)[0] + "/#"

    def held(self, topic: str) -> bool:
        """``topic`` (one of the bridge's own) is held back after a refusal."""
        if not isinstance(topic, str):
            raise InvalidTypeError(f"topic must be a str, not {type(topic).__name__}")
        with self._cond:
            return self._held_locked(topic)

    def _held_locked(self, topic: str) -> bool:
        h = self._held.get(self._kind(topic))
        return h is not None and time.monotonic() < h[0]

    def _send_own(self, topic: str, payload: bytes, retain: bool, gate: bool = False,
                  handed: bool = False) -> bool:
        """One of the bridge's own publications (not an outbox row): its mid is recorded
        as such, so its PUBACK is never matched with a row. True if it waits for its
        PUBACK (``gate``: as the connect phase's publication in flight); with ``handed``,
        True if paho took it at all (even if already answered)."""
        with self._cond:
            if self._held_locked(topic):
                return False
            self._publishing += 1
        info = None
        try:
            info = self.client.publish(topic, payload, qos=1, retain=retain)
        except (ValueError, TypeError) as exc:   # paho refuses the topic or payload
            log.error("cannot publish %s: %s", topic[:200], exc)
        finally:
            with self._cond:
                self._publishing -= 1
                waiting = info is not None and self._own_handed(info, topic)
                if info is not None and waiting and gate and self._own_current == -1:
                    self._own_current = info.mid
                if self._publishing == 0:
                    self._early.clear()   # nothing is being handed to paho: no owner will come
        if handed:
            return info is not None and info.rc != self._mqtt.MQTT_ERR_QUEUE_SIZE
        return waiting

    def _own_handed(self, info: Any, topic: str) -> bool:
        """Under ``_cond``: paho took one of the bridge's own publications under ``info.mid``;
        True while its PUBACK is awaited."""
        if info.mid in self._early:
            self._own_answered(topic, self._early.pop(info.mid))
            return False
        if info.rc == self._mqtt.MQTT_ERR_QUEUE_SIZE:   # paho did not take it
            return False
        self._own[info.mid] = topic
        return True

    def _gate_next(self) -> None:
        """The connect phase: send the next own publication once the previous one is
        answered; with none left (or at GATE_TIMEOUT), let the pump hand rows."""
        while True:
            with self._cond:
                if self._gate_open or not self._connected:
                    return
                if self._own_current is not None and time.monotonic() < self._gate_deadline:
                    return
                item = None
                while self._own_queue and time.monotonic() < self._gate_deadline:
                    cand = self._own_queue.popleft()
                    if not self._held_locked(cand[0]):
                        item = cand
                        break
                if item is None:
                    rest, self._own_queue = list(self._own_queue), collections.deque()
                    self._gate_open = True
                    self._own_current = None
                    self._cond.notify_all()
                else:
                    self._own_current = -1
            if item is None:
                for topic, payload, retain in rest:   # past GATE_TIMEOUT: the rest at once
                    self._send_own(topic, payload, retain)
                return
            if self._send_own(*item, gate=True):
                return   # its PUBACK (or the loss of the connection) moves on
            with self._cond:
                if self._own_current == -1:
                    self._own_current = None

    def _own_answered(self, topic: str, reason: Any) -> None:
        """Under ``_cond``: the broker answered one of the bridge's own publications. A
        refusal is counted and logged under its topic, and holds its kind back."""
        kind = self._kind(topic)
        if reason is None or not getattr(reason, "is_failure", False):
            self._own_strikes.pop(kind, None)
            return
        self._hold(topic, str(reason))

    def _hold(self, topic: str, why: str) -> None:
        """Under ``_cond``: count a refused own publication and hold its kind back."""
        self.refused_own[topic] = self.refused_own.get(topic, 0) + 1
        kind = self._kind(topic)
        self._own_strikes.pop(kind, None)
        lo, hi = self.own_backoff
        prev = self._held.get(kind)
        backoff = lo if prev is None else min(hi, prev[1] * 2)
        self._held[kind] = (time.monotonic() + backoff, backoff)
        log.error("broker refused the bridge's own publication on %s: %s (not an outbox row; %s "
                  "held back for %g s; %d refused on this topic)", topic[:200], why, kind[:200],
                  backoff, self.refused_own[topic])

    def _lost_with_own(self) -> List[int]:
        """Under ``_cond``, on a lost connection with own publications unanswered: the loss
        is theirs (never the rows'); a kind unanswered at PROBE_STRIKES losses in a row is
        counted as refused and held back. Returns their mids, to take back from paho (the
        next connect publishes status, health and discovery afresh)."""
        mids = list(self._own)
        for kind in {self._kind(t) for t in self._own.values()}:
            n = self._own_strikes[kind] = self._own_strikes.get(kind, 0) + 1
            if n >= PROBE_STRIKES:
                topic = next(t for t in self._own.values() if self._kind(t) == kind)
                self._hold(topic, DROPPED_REASON)
        self._own.clear()
        return mids

    def drain(self, timeout: float) -> bool:
        """Wait until every outbox row is acknowledged (True) or ``timeout`` passes."""
        timeout = check_seconds(timeout, "timeout")
        with self._cond:
            return self._cond.wait_for(
                lambda: self.store.pending == 0 and not self._acked and not self._inflight, timeout)

    def stop(self, timeout: float = 5.0) -> None:
        """Publish ``online`` -> ``offline`` cleanly, disconnect and stop the threads."""
        timeout = check_seconds(timeout, "timeout")
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        if self._pump_thread is not None:
            self._pump_thread.join(timeout)
        if self._fleet_thread is not None:
            self._fleet_thread.join(timeout)
        self._flush_acked()
        if self._connected and self._send_own(self.status_topic, b"offline", True):
            with self._cond:
                self._cond.wait_for(lambda: not self._own or not self._connected, timeout)
        if self._connected:
            self.client.disconnect()
        self.client.loop_stop()

    # -- paho callbacks (network thread) ------------------------------------------
    def _stale(self, client: Any) -> bool:
        """A callback of a paho client a switch left behind (None: a caller's own call)."""
        return client is not None and client is not self.client

    def _on_connect_fail(self, client: Any, userdata: Any) -> None:
        # paho calls this from inside its ``except OSError``: the exception is the current one
        if self._stale(client):
            return
        b = self.broker
        self._failed(describe_connect_error(sys.exc_info()[1], b.host, b.port))

    def _failed(self, text: str) -> None:
        """A connection attempt failed: named at once (warning), again on each retry (info, -v).
        With a list of brokers, ``failover.attempts`` failures in a row move to the next."""
        b = self.broker
        with self._cond:
            self._failures += 1
            failures = self._failures
            self.last_error = text
            if len(self.brokers) > 1 and failures >= self.config.failover.attempts and self._want is None:
                self._want = ("switch", self._next_index())
            self._cond.notify_all()
        if failures == 1:
            log.warning("broker %s (retrying every %g..%g s)", text, b.reconnect_min, b.reconnect_max)
        else:
            log.info("broker %s (attempt %d)", text, failures)

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if self._stale(client):
            return   # a client left behind by a switch
        if reason.is_failure:
            b = self.broker
            code = getattr(reason, "value", None)
            if code in _NO_MQTT5 and self._v5[self._index] and b.protocol == "auto":
                with self._cond:   # the fleet thread makes a 3.1.1 client for it
                    if not self._answered_no:   # once per broker: paho may retry (and be
                        self.fallbacks += 1     # refused again) before the swap
                    self._answered_no = True
                    self.last_error = f"{b.address}: refuses MQTT 5 ({reason}): trying 3.1.1"
                    self._want = ("fallback", self._index)
                    self._cond.notify_all()
                return
            if code in _FATAL_CONNACK:
                # no retry can fix it: whoever waits gets BrokerRefusedError (with a list:
                # the next broker, and BrokerRefusedError once every one has refused)
                log.info("broker %s refused the connection: %s", b.address, reason)
                with self._cond:
                    self._bad[self._index] = str(reason)
                    if len(self._bad) < len(self.brokers):
                        self.last_error = f"{b.address}: refused the connection: {reason}"
                        self._want = ("switch", self._next_index())
                        self._cond.notify_all()
                        return
                client.loop_stop()
                with self._cond:
                    self.refused = f"broker refused the connection: {reason}" if len(self.brokers) == 1 \
                        else "every broker refused the connection: " + "; ".join(
                            f"{self.brokers[i].address}: {r}" for i, r in sorted(self._bad.items()))
                    self._cond.notify_all()
            else:
                self._answered_no = True   # its disconnect follows: one failure, this one
                self._failed(f"{b.address}: refused the connection: {reason}")
            return
        self._failures = 0
        self.last_error = None
        with self._cond:
            # the rows paho had in flight are taken back: the pump hands them again, in
            # order, once the connect's own publications are answered (see the docstring)
            mids, self._take_back_mids = self._take_back_mids, []
            if self._inflight:
                mids += list(self._inflight)
                # never raised: probing may have lowered it already, below these rows
                self._last_handed = min(self._last_handed,
                                        min(seq for seq, _ in self._inflight.values()) - 1)
                self._handed_gen += 1
                self._inflight.clear()
            mids += list(self._own)
            self._own.clear()
            self._gate_open = False
            self._gate_deadline = time.monotonic() + GATE_TIMEOUT
            self._own_queue = collections.deque([(self.status_topic, b"online", True)])
            self._own_current = None
        if mids:
            self._take_back(mids)
        b = self.broker
        log.info("connected to %s (broker %d of %d, MQTT %s; session present: %s)", b.address,
                 self._index + 1, len(self.brokers), "5" if self.v5 else "3.1.1", flags.session_present)
        client.subscribe([(f, self.config.qos) for f in [*self.tx_filters, *self.extra]])
        with self._cond:
            self._connected = True
            self.connects += 1
            self._cond.notify_all()
        if self.on_connected is not None:   # its publications queue behind status
            try:
                self.on_connected()
            except Exception:   # never let a hook kill paho's thread
                log.exception("after connect")
        self._gate_next()

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if self._stale(client):
            return   # a client left behind by a switch
        mids: List[int] = []
        with self._cond:
            was = self._connected
            self._connected = self._subscribed = False
            if was:
                self.disconnects += 1
                if self._own and not self._stopping:
                    # one of the bridge's own publications unanswered: the loss is its (a
                    # refusal mosquitto 2.0 follows with a close), never the rows'
                    mids = self._lost_with_own()
                elif self._inflight and not self._stopping:
                    mids = self._lost_with_rows()
            self._own_queue.clear()
            self._own_current = None
            self._gate_open = False
            self._cond.notify_all()
        # taken back from paho at the next CONNACK, before paho re-sends: here paho may be
        # iterating its queue (a failed re-send reports the loss from inside that loop)
        self._take_back_mids.extend(mids)
        if was and not self._stopping:
            log.warning("lost the broker %s (%s); reconnecting with backoff", self.broker.address, reason)
        elif not was and not self._stopping and getattr(reason, "is_failure", False):
            if self._answered_no:   # the CONNACK said why: already counted and named
                self._answered_no = False
                return
            b = self.broker   # dropped before CONNACK (a TLS or protocol failure after TCP)
            self._failed(f"{b.address}: disconnected before the session started: {reason}")

    def _on_subscribe(self, client: Any, userdata: Any, mid: int, reasons: Any, props: Any) -> None:
        if self._stale(client):
            return
        failed = [r for r in reasons if r.is_failure]
        if failed:
            log.error("broker refused the subscription to %s: %s", self.tx_filters, failed[0])
            return
        with self._cond:
            self._subscribed = True
            self._cond.notify_all()

    def _on_publish(self, client: Any, userdata: Any, mid: int, reason: Any, props: Any) -> None:
        if self._stale(client):
            return   # an answer of a broker left behind: its rows are handed again
        gate = False
        with self._cond:
            entry = self._inflight.pop(mid, None)
            if entry is not None:
                self._acked_at = time.monotonic()
            if entry is None:
                own = self._own.pop(mid, None)
                if own is not None:
                    self._own_answered(own, reason)
                    if mid == self._own_current:
                        self._own_current = None
                        gate = True
                elif self._publishing:   # perhaps for the publish() call now running
                    self._early[mid] = reason
                # else: a mid nobody waits for (a repeated PUBACK): dropped, never kept
            else:
                self._acked_one(entry, reason)
                self._settled(entry[0])
            # wake the pump for a batch of acknowledgements, not for each one (one disk
            # transaction per batch); the last one of a burst always wakes it
            if len(self._acked) >= self._batch or not self._inflight or not self._own:
                self._cond.notify_all()
        if gate:   # the connect phase's publication answered: the next one
            self._gate_next()

    def _acked_one(self, entry: Tuple[int, str], reason: Any) -> None:
        """Under ``_cond``: the broker answered publication ``entry``. A refusal (MQTT 5
        reason >= 0x80, e.g. not authorised) is counted and logged: no retry can fix it, so
        the row leaves the outbox like a success, but never silently."""
        seq, topic = entry
        self._acked.append(seq)
        if reason is not None and getattr(reason, "is_failure", False):
            key = str(reason)
            self.refused_pubs[key] = self.refused_pubs.get(key, 0) + 1
            n = self.refused_total
            if n <= _LOG_FIRST or n % 1000 == 0:
                log.error("broker refused publication seq %d on %s: %s (%d refused so far)",
                          seq, topic, reason, n)

    def _settled(self, seq: int) -> None:
        """Under ``_cond``: row ``seq`` got its answer: the losses before it were not its fault."""
        self._lost_in_flight = 0
        self._strikes.pop(seq, None)
        if self._probe_until and seq >= self._probe_until:
            log.info("probing done: every row in flight at the losses is settled")
            self._probe_until = 0
            self._cond.notify_all()

    def _lost_with_rows(self) -> List[int]:
        """Under ``_cond``, on a lost connection with rows in flight: count the loss, strike a
        lone row while probing (refused at the last strike), start probing after
        :data:`PROBE_AFTER` losses. Returns the paho mids to take back from paho."""
        self._lost_in_flight += 1
        if self._probe_until:
            if len(self._inflight) == 1:
                (mid, entry), = self._inflight.items()
                n = self._strikes[entry[0]] = self._strikes.get(entry[0], 0) + 1
                if n >= PROBE_STRIKES:
                    del self._inflight[mid]
                    self._acked_one(entry, _Dropped())
                    self._settled(entry[0])
                    return [mid]
            return []
        if self._lost_in_flight < PROBE_AFTER:
            return []
        seqs = sorted(seq for seq, _ in self._inflight.values())
        log.warning("the broker closed the connection %d times with rows %d..%d in flight and "
                    "no acknowledgement: sending them one at a time", self._lost_in_flight,
                    seqs[0], seqs[-1])
        self._probe_until = seqs[-1]
        self._last_handed = seqs[0] - 1      # the pump hands them again, one by one
        self._handed_gen += 1
        mids = list(self._inflight)
        self._inflight.clear()
        return mids

    def _take_back(self, mids: List[int]) -> None:
        """Drop ``mids`` from paho's session so paho does not re-send them at the reconnect.
        paho 2.x has no public call for it; its queue is ``_out_messages`` under
        ``_out_message_mutex`` (taken here without ``_cond``: paho calls us holding it), and
        this runs from ``on_connect``, which paho calls before its re-send loop."""
        out = getattr(self.client, "_out_messages", None)
        lock = getattr(self.client, "_out_message_mutex", None)
        if out is None or lock is None:   # another paho: it re-sends them, the rows stay counted
            log.warning("cannot take rows back from this paho-mqtt; they are re-sent as a burst")
            return
        with lock:
            for mid in mids:
                out.pop(mid, None)

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        handler = self.extra.get(msg.topic)
        if handler is not None:
            try:
                handler(msg.payload)
            except Exception:   # one bad message must not kill paho's thread
                log.exception("message on %s", msg.topic[:200])
            return
        expiry = getattr(getattr(msg, "properties", None), "MessageExpiryInterval", None)
        deadline = None if expiry is None else time.monotonic() + expiry
        try:
            self._on_tx(msg.topic, msg.payload, deadline)
        except Exception:   # one bad message must not kill paho's thread
            log.exception("tx on %s failed", msg.topic[:200])

    # -- outbox pump -------------------------------------------------------------
    def _flush_acked(self) -> None:
        with self._cond:
            acked, self._acked = self._acked, []
        if acked:
            try:
                self.store.delete(acked)
            except StoreError as exc:   # kept for the next round: a row is never lost here
                log.warning("%s (retried)", exc)
                with self._cond:
                    self._acked[:0] = acked
                return
            self.published += len(acked)
            with self._cond:
                self._cond.notify_all()

    def notify(self) -> None:
        """New rows are in the outbox."""
        with self._cond:
            self._cond.notify_all()

    @property
    def _window(self) -> int:
        """Rows that may be in flight: one while probing."""
        return 1 if self._probe_until else self.config.inflight

    @property
    def probing(self) -> bool:
        """The pump sends one row at a time (see the module's docstring)."""
        return bool(self._probe_until)

    def _ready(self) -> bool:
        """A round is worth it: a batch of acknowledgements to delete, or room for a batch
        of new rows (or for the last ones: the window is empty)."""
        if self._stopping or len(self._acked) >= self._batch:
            return True
        room = self._window - len(self._inflight)
        unsent = self.store.pending - len(self._inflight) - len(self._acked)
        return self._rows_allowed() and unsent > 0 and (room >= self._batch or not self._inflight)

    def _rows_allowed(self) -> bool:
        """Under ``_cond``: rows may be handed: connected, and the connect's own
        publications answered (or GATE_TIMEOUT passed: the pump opens the gate then),
        and no failback waiting for the rows in flight."""
        return self._connected and self._gate_open and not self._draining

    def _work(self) -> bool:
        """Anything at all to do (the pump's round after ``PUMP_LINGER``)."""
        return bool(self._acked) or (self._rows_allowed() and len(self._inflight) < self._window
                                     and self.store.pending > len(self._inflight) + len(self._acked))

    def _pump(self) -> None:
        while True:
            with self._cond:
                # a batch now, or whatever there is after PUMP_LINGER (never a round per PUBACK)
                if not self._cond.wait_for(self._ready, PUMP_LINGER) and not self._work():
                    self._cond.wait_for(lambda: self._stopping or self._work(), 1.0)
                if self._stopping:
                    return
                late = self._connected and not self._gate_open and time.monotonic() >= self._gate_deadline
            if late:   # an own publication's PUBACK that never came: the rows wait no longer
                self._gate_next()
            with self._cond:
                room = self._window - len(self._inflight) if self._rows_allowed() else 0
            try:
                self._pump_once(room)
            except StoreError as exc:   # a disk that fails a read: try again next round
                log.warning("%s (retried)", exc)
                with self._cond:
                    self._cond.wait(1.0)

    def _pump_once(self, room: int) -> None:
        self._flush_acked()
        if room <= 0:
            return
        qos = self.config.qos
        with self._cond:
            # rows answered but not yet deleted, or in paho's hands: never handed twice
            skip = set(self._acked) | {seq for seq, _ in self._inflight.values()}
            start, gen = self._last_handed, self._handed_gen
        for seq, topic, payload, retain in self.store.after(start, room + len(skip)):
            if seq in skip:
                continue
            if room <= 0:
                break
            room -= 1
            props = None
            if self.v5:   # the consumer's dedup key without parsing the payload
                props = self._props[0](self._props[1].PUBLISH)
                props.UserProperty = [("host", self.config.host), ("seq", str(seq))]
            # paho keeps what it could not send (even QoS 0) and sends it on reconnect
            with self._cond:
                self._publishing += 1
            try:
                info = self.client.publish(topic, payload, qos=qos, retain=retain, properties=props)
            except BaseException:
                with self._cond:
                    self._publishing -= 1
                raise
            with self._cond:
                self._publishing -= 1
                if info.rc == self._mqtt.MQTT_ERR_QUEUE_SIZE:
                    # paho still holds an unanswered message under this mid: not queued,
                    # handed again in a later round
                    if self._publishing == 0:
                        self._early.clear()
                    return
                self._own.pop(info.mid, None)   # a stale own publication's mid, reused
                if info.mid in self._early:
                    self._acked_one((seq, topic), self._early.pop(info.mid))
                    self._settled(seq)
                else:
                    if not self._inflight:   # the window's clock starts with its first row
                        self._acked_at = time.monotonic()
                    self._inflight[info.mid] = (seq, topic)
                if self._publishing == 0:
                    self._early.clear()
                if gen != self._handed_gen:   # probing took rows back meanwhile: start again
                    return
                self._last_handed = max(self._last_handed, seq)
