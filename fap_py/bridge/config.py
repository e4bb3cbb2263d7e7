"""The bridge's configuration: a TOML file read into checked dataclasses.

docs/bridge.md has the reference; every key is checked here, so that a
typo stops the bridge at start-up with the key's name instead of failing
later on the bus.
"""
from __future__ import annotations

import os
import socket
import sys
from dataclasses import dataclass, field
from typing import Any, Dict, Mapping, Optional, Tuple
from urllib.parse import unquote, urlsplit

from .. import _protocols
from .._validate import baud_rates, check_int
from ..errors import FapError, InvalidTypeError, InvalidValueError
from ..fap import RS485, RS485Mode
from ..port import port_kind
from ..rs485 import DEFAULT_BAUD, parse_realtime
from ._schema import BridgeConfigError, BridgeConfigTypeError
from ._schema import done as _done
from ._schema import in_range as _range
from ._schema import pop as _pop
from ._schema import show as _show
from .files import CONFIG_MAX, SECRET_MAX, TLS_FILE_MAX, check_port, check_state_dir, read_bounded

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python < 3.11 only
    import tomli as tomllib

_RS485_MODES = {"auto": RS485Mode.AUTO, "kernel": RS485Mode.KERNEL,
                "soft": RS485Mode.SOFT_RTS, "none": RS485Mode.NONE, "gpio": RS485Mode.GPIO}
_NODE_BYTE = 0xFF   #: a node number on a topic is one address byte, whatever the protocol


@dataclass(frozen=True)
class BusConfig:
    """One bus: a port, a protocol, a role, the line keys every protocol shares, and
    ``options``: the protocol's own keys, checked by its plug-in
    (``fap_py.bridge.protocols.<protocol>``, e.g. a FAP master's ``slaves``).

    ``protocol`` is the protocol's one name (a file's alias, ``execasync``, is read as
    ``exec``). The protocol's own keys also read as attributes, as before the plug-ins:
    ``cfg.slaves`` is ``cfg.options.slaves``.
    """

    name: str
    port: str
    protocol: str
    role: str = "master"
    # -- the line keys every protocol shares (one place: a new common key goes here) --
    baud: int = DEFAULT_BAUD
    rs485: RS485 = field(default_factory=RS485)
    timeout: float = 0.1           #: per transaction attempt (fap: how long a tx waits for queue room)
    retries: int = 2
    poll_interval: float = 1.0
    reopen_interval: float = 5.0   #: seconds between attempts to open a port that failed
    homeassistant: bool = False    #: publish Home Assistant MQTT discovery for its nodes
    sparkplug: bool = False        #: its nodes are Sparkplug B devices (needs [sparkplug])
    # -- the protocol's own keys (its plug-in's Options) --
    options: Any = None

    def __getattr__(self, name: str) -> Any:
        options = self.__dict__.get("options")
        if options is None or name.startswith("__"):
            raise AttributeError(name)
        return getattr(options, name)


@dataclass(frozen=True)
class BrokerConfig:
    """Where the broker is and how to log in."""

    host: str
    port: int
    tls: bool
    username: Optional[str] = None
    password: Optional[str] = None
    ca: Optional[str] = None
    cert: Optional[str] = None
    key: Optional[str] = None
    client_id: Optional[str] = None
    keepalive: int = 30
    reconnect_min: float = 0.5
    reconnect_max: float = 30.0
    connect_timeout: float = 10.0
    #: seconds with rows in flight and no PUBACK before the connection is made anew
    ack_timeout: float = 30.0
    #: MQTT "5", "3.1.1", or "auto": 5, and 3.1.1 for a broker that refuses 5
    protocol: str = "auto"
    session_expiry: int = 604_800  #: MQTT 5: seconds the broker keeps our session while we are away

    @property
    def address(self) -> str:
        """``host:port`` (``[v6]:port``): how logs, health and metrics name this broker."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    @property
    def url(self) -> str:
        """``mqtt://host:port`` or ``mqtts://host:port`` (no credentials)."""
        return f"{'mqtts' if self.tls else 'mqtt'}://{self.address}"


@dataclass(frozen=True)
class FailoverConfig:
    """``[failover]``: how the bridge moves between the brokers of a ``[[broker]]`` list."""

    attempts: int = 2               #: failed connection attempts on one broker before the next
    failback: bool = True           #: go back to an earlier broker of the list when it answers
    failback_interval: float = 30.0  #: seconds between probes of the earlier brokers
    drain: float = 2.0              #: seconds a failback waits for the rows in flight first


@dataclass(frozen=True)
class SparkplugConfig:
    """``[sparkplug]``: the bridge as a Sparkplug B edge node."""

    group_id: str
    edge_node_id: str
    #: Sparkplug 3.0 primary host application: births and data wait for its STATE online
    primary_host_id: Optional[str] = None


@dataclass(frozen=True)
class BridgeConfig:
    """The whole file."""

    broker: BrokerConfig
    buses: Tuple[BusConfig, ...]
    host: str
    prefix: str = "fap"
    qos: int = 1
    state_dir: str = "."
    queue_max: int = 100_000
    seen_max: int = 10_000
    stats_interval: float = 10.0
    inflight: int = 100
    metrics_listen: Optional[Tuple[str, int]] = None   #: [metrics] listen: Prometheus endpoint
    #: [metrics] sim_control: a ``fap sim`` control socket (unix:PATH) whose counters join the metrics
    metrics_sim_control: Optional[str] = None
    discovery_prefix: str = "homeassistant"             #: Home Assistant's discovery prefix
    sparkplug: Optional[SparkplugConfig] = None         #: [sparkplug]
    #: every broker, in order of preference ([[broker]]); ``broker`` is the first
    brokers: Tuple[BrokerConfig, ...] = ()
    failover: FailoverConfig = field(default_factory=FailoverConfig)

    def __post_init__(self) -> None:
        if not self.brokers:
            object.__setattr__(self, "brokers", (self.broker,))


def check_bus_node(bus: Any, node: Any) -> None:
    """InvalidTypeError / InvalidValueError unless ``bus`` is a bus name (str) and ``node``
    a node number (one address byte): what the bridge's per-node calls are handed."""
    if not isinstance(bus, str):
        raise InvalidTypeError(f"bus must be a str, not {type(bus).__name__}")
    check_int(node, "node", 0, _NODE_BYTE)


# -- the common keys (a protocol's own keys are checked by its plug-in) --------------

def _rs485(t: Dict[str, Any], where: str) -> RS485:
    mode = _pop(t, "rs485", str, where, "auto")
    if mode not in _RS485_MODES:
        raise BridgeConfigError(f"{where}.rs485 must be one of {', '.join(_RS485_MODES)}, not {_show(mode)}")
    before = _range(_pop(t, "rts_before", (int, float), where, 0), 0, 1000, f"{where}.rts_before")
    after = _range(_pop(t, "rts_after", (int, float), where, 0), 0, 1000, f"{where}.rts_after")
    polarity = _pop(t, "rts_polarity", str, where, "high")
    if polarity not in ("high", "low"):
        raise BridgeConfigError(f"{where}.rts_polarity must be high or low, not {_show(polarity)}")
    echo = _pop(t, "echo_suppression", bool, where, False)
    # rs485 = "gpio": a GPIO line is the DE/RE pin (rts_* are its level and delays)
    chip = _pop(t, "gpio_chip", str, where, None) if mode == "gpio" else None
    line = _pop(t, "gpio_line", int, where, 0) if mode == "gpio" else None
    if mode == "gpio":
        if not chip:
            raise BridgeConfigError(f"{where}.gpio_chip: rs485 = \"gpio\" needs the DE/RE line's "
                                    "/dev/gpiochipN")
        line = _range(line, 0, 1023, f"{where}.gpio_line")
    elif "gpio_chip" in t or "gpio_line" in t:
        raise BridgeConfigError(f"{where}: gpio_chip and gpio_line need rs485 = \"gpio\"")
    # the engine's I/O thread real-time: "fifo:50,mlock,cpu=1" (docs/realtime.md)
    realtime = _pop(t, "realtime", str, where, None)
    if realtime is not None:
        try:
            parse_realtime(realtime, f"{where}.realtime")
        except InvalidValueError as exc:
            raise BridgeConfigError(str(exc)) from None
    try:
        return RS485(mode=_RS485_MODES[mode], rts_active_high=polarity == "high",
                     delay_before_send_us=int(before * 1000), delay_after_send_us=int(after * 1000),
                     echo_suppression=echo, gpio_chip=chip, gpio_line=line, realtime=realtime)
    except FapError as exc:
        raise BridgeConfigError(f"{where}: {exc}") from None


def _bus(t: Dict[str, Any], index: int) -> BusConfig:
    where = f"bus[{index}]"
    name = _pop(t, "name", str, where)
    if not name or any(c in name for c in "/+#"):
        raise BridgeConfigError(f"{where}.name {_show(name)}: empty or holds an MQTT wildcard or /")
    where = f"bus {_show(name)}"
    port = _pop(t, "port", str, where)
    text = _pop(t, "protocol", str, where)
    try:
        proto = _protocols.get(text)
        plugin = proto.plugin("bridge")
    except _protocols.UnknownProtocolError:
        with_bridge = [p.name for p in _protocols.all_protocols() if p.has_plugin("bridge")]
        raise BridgeConfigError(f"{where}.protocol must be one of {', '.join(with_bridge)}, "
                                f"not {_show(text)}") from None
    role = _pop(t, "role", str, where, "master")
    if role not in plugin.ROLES:
        raise BridgeConfigError(f"{where}.role {_show(role)}: a {proto.name} bus is "
                                f"{' or '.join(plugin.ROLES)}")
    kw: Dict[str, Any] = {"name": name, "port": port, "protocol": proto.name, "role": role}
    kw["baud"] = _pop(t, "baud", int, where, proto.default_baud)
    if kw["baud"] not in baud_rates():
        raise BridgeConfigError(f"{where}.baud {_show(kw['baud'])} is not a rate the serial port layer "
                                f"supports ({', '.join(map(str, baud_rates()))})")
    kw["rs485"] = _rs485(t, where)   # every protocol opens its port through the C port layer
    kw["timeout"] = _range(float(_pop(t, "timeout", (int, float), where, plugin.DEFAULT_TIMEOUT)),
                           0.001, 3600, f"{where}.timeout")
    kw["retries"] = _range(_pop(t, "retries", int, where, 2), 0, 1000, f"{where}.retries")
    kw["poll_interval"] = _range(float(_pop(t, "poll_interval", (int, float), where, 1.0)),
                                 0.001, 86400, f"{where}.poll_interval")
    kw["homeassistant"] = _pop(t, "homeassistant", bool, where, False)
    kw["sparkplug"] = _pop(t, "sparkplug", bool, where, False)
    kw["reopen_interval"] = _range(float(_pop(t, "reopen_interval", (int, float), where, 5.0)),
                                   0.01, 3600, f"{where}.reopen_interval")
    kw["options"] = plugin.options(t, where, role, proto)   # the protocol's own keys
    _done(t, where)
    return BusConfig(**kw)


def bus_from_dict(table: Mapping[str, Any], index: int = 0) -> BusConfig:
    """One checked :class:`BusConfig` from a ``[[bus]]`` table (its common keys here, its
    protocol's own keys by the protocol's plug-in)."""
    if not isinstance(table, Mapping):
        raise BridgeConfigError(f"bus[{index}] must be a table ([[bus]]), not {type(table).__name__}")
    return _bus(dict(table), index)


def is_network_port(port: str) -> bool:
    """``port`` is a URL, not a device path: the C port layer's own reading
    (:func:`fap_py.port.port_kind`), so no device path is ever taken for a
    URL or the other way. A URL libfap does not open is still a URL here,
    refused by :func:`_check_network_port` with the reason."""
    if not isinstance(port, str):
        raise BridgeConfigTypeError(f"port must be a str, not {type(port).__name__}")
    return port_kind(port) != "device"


def _port_key(port: str, base: str) -> str:
    """What makes two ports the same: a network port's scheme, host and port (case folded),
    a device's real path (symlinks resolved)."""
    if is_network_port(port):
        parts = urlsplit(port)
        try:
            return f"{parts.scheme.lower()}://{(parts.hostname or '').lower()}:{parts.port}"
        except ValueError:   # a bad port number: the open says so; compared as written
            return port.lower()
    return os.path.realpath(os.path.join(base, port))


_HOST_MAX = 253   #: characters of a DNS name (RFC 1035), and so of a broker's host


def parse_url(url: str) -> Tuple[str, int, bool, Optional[str], Optional[str]]:
    """``mqtt://[user:pass@]host[:port]`` or ``mqtts://...`` -> host, port, tls, user, password."""
    if not isinstance(url, str):
        raise BridgeConfigTypeError(f"broker.url must be a string, not {type(url).__name__}")
    try:
        url.encode("utf-8")
    except UnicodeEncodeError as exc:   # a lone surrogate: no broker has such a name
        raise BridgeConfigError(f"broker.url holds a character that is not text (a lone surrogate "
                                f"at position {exc.start}): {_show(url)}") from None
    try:
        parts = urlsplit(url)
        hostname = parts.hostname
    except ValueError as exc:   # "mqtt://[::1": an unclosed IPv6 bracket
        raise BridgeConfigError(f"broker.url {_show(url)}: {exc}") from None
    if parts.scheme not in ("mqtt", "mqtts") or not hostname:
        raise BridgeConfigError(f"broker.url must be mqtt://host[:port] or mqtts://host[:port], not {_show(url)}")
    if len(hostname) > _HOST_MAX:
        raise BridgeConfigError(f"broker.url: a host of {len(hostname)} characters (at most {_HOST_MAX}): "
                                f"{_show(url)}")
    try:
        hostname.encode("idna")
    except UnicodeError:   # an empty label (a..b), a label over 63 characters ...
        raise BridgeConfigError(f"broker.url: {_show(hostname)} is not a host name") from None
    tls = parts.scheme == "mqtts"
    try:
        port = parts.port or (8883 if tls else 1883)
    except ValueError:
        raise BridgeConfigError(f"broker.url has a bad port: {_show(url)}") from None
    user = unquote(parts.username) if parts.username else None
    password = unquote(parts.password) if parts.password else None
    return hostname, port, tls, user, password


def _broker(t: Dict[str, Any], base: str, where: str = "broker") -> BrokerConfig:
    host, port, tls, user, password = parse_url(_pop(t, "url", str, where))
    kw: Dict[str, Any] = {"host": host, "port": port, "tls": tls}
    kw["username"] = _pop(t, "username", str, where, user)
    kw["password"] = _pop(t, "password", str, where, password)
    pw_file = _pop(t, "password_file", str, where, None)
    if pw_file is not None:
        raw = read_bounded(os.path.join(base, pw_file), SECRET_MAX, f"{where}.password_file")
        try:
            kw["password"] = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise BridgeConfigError(f"{where}.password_file {_show(pw_file)} is not UTF-8 text") from None
    for key in ("ca", "cert", "key"):
        value = _pop(t, key, str, where, None)
        if value is not None:
            if not tls:
                raise BridgeConfigError(f"{where}.{key} needs an mqtts:// url")
            kw[key] = os.path.join(base, value)
    if (kw.get("cert") is None) != (kw.get("key") is None):
        raise BridgeConfigError(f"{where}.cert and {where}.key go together")
    kw["client_id"] = _pop(t, "client_id", str, where, None)
    kw["keepalive"] = _range(_pop(t, "keepalive", int, where, 30), 5, 3600, f"{where}.keepalive")
    kw["reconnect_min"] = _range(float(_pop(t, "reconnect_min", (int, float), where, 0.5)), 0.01, 3600,
                                 f"{where}.reconnect_min")
    kw["reconnect_max"] = _range(float(_pop(t, "reconnect_max", (int, float), where, 30.0)),
                                 kw["reconnect_min"], 3600, f"{where}.reconnect_max")
    kw["connect_timeout"] = _range(float(_pop(t, "connect_timeout", (int, float), where, 10.0)), 0.1, 3600,
                                   f"{where}.connect_timeout")
    kw["ack_timeout"] = _range(float(_pop(t, "ack_timeout", (int, float), where, 30.0)), 0.1, 3600,
                               f"{where}.ack_timeout")
    kw["protocol"] = _pop(t, "protocol", str, where, "auto")
    if kw["protocol"] not in ("5", "3.1.1", "auto"):
        raise BridgeConfigError(f"{where}.protocol must be \"5\", \"3.1.1\" or \"auto\", "
                                f"not {_show(kw['protocol'])}")
    kw["session_expiry"] = _range(_pop(t, "session_expiry", int, where, 604_800), 0, 0xFFFFFFFF,
                                  f"{where}.session_expiry")
    _done(t, where)
    return BrokerConfig(**kw)


def from_dict(data: Mapping[str, Any], base: str = ".") -> BridgeConfig:
    """A checked :class:`BridgeConfig` from parsed TOML; relative paths are relative to ``base``."""
    if not isinstance(data, Mapping):
        raise BridgeConfigError(f"the configuration must be a table, not {type(data).__name__}")
    top = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    brokers = _brokers(top.pop("broker", None), base)
    failover = _failover(top.pop("failover", {}))
    bridge = top.pop("bridge", {})
    if not isinstance(bridge, dict):
        raise BridgeConfigError("[bridge] must be a table")
    bus_tables = top.pop("bus", None)
    if not isinstance(bus_tables, list) or not bus_tables:
        raise BridgeConfigError("at least one [[bus]] table is needed")
    metrics = top.pop("metrics", {})
    if not isinstance(metrics, dict):
        raise BridgeConfigError("[metrics] must be a table")
    sparkplug = top.pop("sparkplug", None)
    if sparkplug is not None and not isinstance(sparkplug, dict):
        raise BridgeConfigError("[sparkplug] must be a table")
    _done(top, "top level")
    for i, b in enumerate(bus_tables):   # [[bus]] only: a list of lists is not a table
        if not isinstance(b, dict):
            raise BridgeConfigError(f"bus[{i}] must be a table ([[bus]]), not {type(b).__name__}")
    buses = tuple(bus_from_dict(b, i) for i, b in enumerate(bus_tables))
    names = [b.name for b in buses]
    if len(set(names)) != len(names):
        raise BridgeConfigError(f"bus names must differ: {_show(names)}")
    if "bridge" in names:
        raise BridgeConfigError("a bus may not be called 'bridge' (that topic holds the bridge status)")
    seen_ports: Dict[str, str] = {}
    for b in buses:   # one engine per port: a second bus on it would stay unavailable for good
        key = _port_key(b.port, base)
        if key in seen_ports:
            raise BridgeConfigError(f"bus {_show(b.name)}.port {_show(b.port)}: bus "
                                    f"{_show(seen_ports[key])} already uses that port")
        seen_ports[key] = b.name
    where = "bridge"
    host = _pop(bridge, "host", str, where, socket.gethostname())
    prefix = _pop(bridge, "topic_prefix", str, where, "fap").strip("/")
    if not prefix or any(c in prefix for c in "+#"):
        raise BridgeConfigError(f"bridge.topic_prefix {_show(prefix)}: empty or holds a wildcard")
    if not host or any(c in host for c in "/+#"):
        raise BridgeConfigError(f"bridge.host {_show(host)}: empty or holds / or a wildcard")
    kw: Dict[str, Any] = {"broker": brokers[0], "brokers": brokers, "failover": failover,
                          "buses": buses, "host": host, "prefix": prefix}
    kw["qos"] = _range(_pop(bridge, "qos", int, where, 1), 0, 2, "bridge.qos")
    # under systemd, StateDirectory= sets $STATE_DIRECTORY: the default when the file names none
    default_state = os.environ.get("STATE_DIRECTORY", ".").split(":")[0] or "."
    kw["state_dir"] = os.path.join(base, _pop(bridge, "state_dir", str, where, default_state))
    kw["queue_max"] = _range(_pop(bridge, "queue_max", int, where, 100_000), 10, 100_000_000, "bridge.queue_max")
    kw["seen_max"] = _range(_pop(bridge, "seen_max", int, where, 10_000), 10, 10_000_000, "bridge.seen_max")
    kw["stats_interval"] = _range(float(_pop(bridge, "stats_interval", (int, float), where, 10.0)),
                                  0.05, 86400, "bridge.stats_interval")
    kw["inflight"] = _range(_pop(bridge, "inflight", int, where, 100), 1, 65535, "bridge.inflight")
    disc = _pop(bridge, "discovery_prefix", str, where, "homeassistant").strip("/")
    if not disc or any(c in disc for c in "+#"):
        raise BridgeConfigError(f"bridge.discovery_prefix {_show(disc)}: empty or holds a wildcard")
    kw["discovery_prefix"] = disc
    _done(bridge, where)
    listen = _pop(metrics, "listen", str, "metrics", None)
    if listen is not None:
        kw["metrics_listen"] = parse_listen(listen)
    sim_control = _pop(metrics, "sim_control", str, "metrics", None)
    if sim_control is not None:
        from ..sim._control import ControlError, unix_path

        if listen is None:
            raise BridgeConfigError("metrics.sim_control needs metrics.listen (the endpoint it joins)")
        try:
            unix_path(sim_control)
        except ControlError as exc:
            raise BridgeConfigError(f"metrics.sim_control: {exc}") from None
        kw["metrics_sim_control"] = sim_control
    _done(metrics, "metrics")
    if sparkplug is not None:
        ids = {}
        for key, default in (("group_id", ...), ("edge_node_id", host), ("primary_host_id", None)):
            value = _pop(sparkplug, key, str, "sparkplug", default)
            if value is None:
                continue
            if not value or any(c in value for c in "/+#"):
                raise BridgeConfigError(f"sparkplug.{key} {_show(value)}: empty or holds / or a wildcard")
            ids[key] = value
        _done(sparkplug, "sparkplug")
        kw["sparkplug"] = SparkplugConfig(**ids)
    elif any(b.sparkplug for b in buses):
        raise BridgeConfigError("a bus with sparkplug = true needs a [sparkplug] table (group_id)")
    return BridgeConfig(**kw)


_BROKERS_MAX = 32   #: brokers in a [[broker]] list


def _brokers(value: Any, base: str) -> Tuple[BrokerConfig, ...]:
    """``[broker]`` (one) or ``[[broker]]`` (an ordered list, the first preferred)."""
    if isinstance(value, dict):
        return (_broker(value, base),)
    if not isinstance(value, list) or not value:
        raise BridgeConfigError("missing [broker] table (or a [[broker]] list)")
    if len(value) > _BROKERS_MAX:
        raise BridgeConfigError(f"[[broker]]: {len(value)} brokers (at most {_BROKERS_MAX})")
    out = []
    for i, t in enumerate(value):
        if not isinstance(t, dict):
            raise BridgeConfigError(f"broker[{i}] must be a table ([[broker]]), not {type(t).__name__}")
        out.append(_broker(dict(t), base, f"broker[{i}]"))
    seen: Dict[Tuple[str, int], int] = {}
    for i, b in enumerate(out):
        key = (b.host.lower(), b.port)
        if key in seen:
            raise BridgeConfigError(f"broker[{i}] {b.address}: the same broker as broker[{seen[key]}]")
        seen[key] = i
    return tuple(out)


def _failover(t: Any) -> FailoverConfig:
    """``[failover]``: the policy between the brokers of the list."""
    if not isinstance(t, dict):
        raise BridgeConfigError("[failover] must be a table")
    t = dict(t)
    where = "failover"
    kw: Dict[str, Any] = {}
    kw["attempts"] = _range(_pop(t, "attempts", int, where, 2), 1, 1000, "failover.attempts")
    kw["failback"] = _pop(t, "failback", bool, where, True)
    kw["failback_interval"] = _range(float(_pop(t, "failback_interval", (int, float), where, 30.0)),
                                     0.05, 86400, "failover.failback_interval")
    kw["drain"] = _range(float(_pop(t, "drain", (int, float), where, 2.0)), 0, 600, "failover.drain")
    _done(t, where)
    return FailoverConfig(**kw)


def parse_listen(text: str) -> Tuple[str, int]:
    """``host:port`` or ``[v6]:port`` -> (host, port), for ``[metrics] listen``."""
    if not isinstance(text, str):
        raise BridgeConfigTypeError(f"metrics.listen must be a string, not {type(text).__name__}")
    host, sep, port = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port.isascii() or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise BridgeConfigError(f"metrics.listen must be host:port, e.g. 127.0.0.1:9464, not {_show(text)}")
    return host, int(port)


def verify_files(cfg: BridgeConfig, ports: bool = True) -> None:
    """Check every file the configuration names (BridgeFileError, exit 3, at the first bad one):
    the TLS files, the state directory and, with ``ports``, every bus's port. Creates nothing."""
    if not isinstance(cfg, BridgeConfig):
        raise BridgeConfigTypeError(f"verify_files needs a BridgeConfig, not {type(cfg).__name__}")
    for i, b in enumerate(cfg.brokers):
        where = "broker" if len(cfg.brokers) == 1 else f"broker[{i}]"
        for key in ("ca", "cert", "key"):
            path = getattr(b, key)
            if path is not None:
                read_bounded(path, TLS_FILE_MAX, f"{where}.{key}")
    check_state_dir(cfg.state_dir)
    if ports:
        for bus in cfg.buses:
            if is_network_port(bus.port):   # the bridge opens it itself: checked, not connected
                _check_network_port(bus.port, f"bus {bus.name!r}.port")
            else:
                check_port(bus.port, f"bus {bus.name!r}.port")


def _check_network_port(port: str, field: str) -> None:
    """A ``tcp://`` / ``rfc2217://`` port the C port layer can parse (a host and a
    port 1..65535, known query parameters: ``fap_port_kind``); opens nothing."""
    import errno

    from .files import BridgeFileError

    kind = port_kind(port)
    if kind in ("tcp", "rfc2217"):
        return
    if kind == "other":
        why = (f"a URL port is tcp://HOST:PORT or rfc2217://HOST:PORT, "
               f"not {_show(port.split('://', 1)[0])}://")
    else:
        why = "a URL port needs a host and a port 1..65535 (tcp://HOST:PORT) and known options"
    raise BridgeFileError(errno.EINVAL, field, _show(port, 100), why)


def load(path: "str | os.PathLike[str]") -> BridgeConfig:
    """Read and check a bridge.toml (a regular file of at most 1 MiB of UTF-8).

    Raises:
        BridgeConfigTypeError: ``path`` is not a path (an int is not taken as a file descriptor).
        BridgeFileError: the file cannot be read, is not a regular file or is too big (an OSError).
        BridgeConfigError: not UTF-8, bad TOML or a bad value.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise BridgeConfigTypeError(f"the configuration path must be a str or os.PathLike, "
                                    f"not {type(path).__name__}")
    path = os.fspath(path)
    if not isinstance(path, str):
        raise BridgeConfigTypeError("the configuration path must be text, not bytes")
    raw = read_bounded(path, CONFIG_MAX, "configuration")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BridgeConfigError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BridgeConfigError(f"{path}: {exc}") from None
    except RecursionError:   # tomllib recurses per nesting level: "a = [[[[..."
        raise BridgeConfigError(f"{path}: arrays or tables nested too deeply") from None
    except ValueError as exc:   # an integer of more than 4300 digits (int() refuses it)
        raise BridgeConfigError(f"{path}: {str(exc).split(':')[0]}") from None
    return from_dict(data, os.path.dirname(os.path.abspath(path)))


__all__ = ["BridgeConfig", "BridgeConfigError", "BridgeConfigTypeError", "BrokerConfig", "BusConfig",
           "FailoverConfig",
           "check_bus_node", "bus_from_dict",
           "SparkplugConfig", "from_dict", "load", "parse_listen", "parse_url", "verify_files"]
