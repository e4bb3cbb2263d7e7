"""Home Assistant MQTT discovery for the nodes of the buses that ask for it (``homeassistant = true``).

One Home Assistant device per node, with entities that read the bridge's
own topics (nothing extra is published for them): the node's state and
last-seen time (``.../state``), its last message (``.../rx``) and its
counters and last reply time (``<prefix>/<bus>/stats``, ``nodes`` and
``health``). Every entity's availability is the bridge's status topic, so
the last will marks them all unavailable when the bridge dies.

The configurations are retained and published outside the outbox (their
payloads are Home Assistant's schema, without the bridge's ``seq``/``ts``
fields): on every connect, when Home Assistant announces itself on
``<discovery_prefix>/status``, and when a node not seen before appears.
Unique ids are built from host, bus, node and entity only: stable across
restarts.
"""
from __future__ import annotations

import json
import re
import threading
from typing import Any, Callable, Dict, List, Set, Tuple

from .. import _protocols
from .._project import docs_url
from ..errors import InvalidTypeError, InvalidValueError
from .config import BridgeConfig, BusConfig, check_bus_node

_ORIGIN = {"name": "fap_py bridge", "support_url": docs_url("bridge.md")}

# (component, key, name, fields): {node} and {stats}/{state}/{rx} are filled in per node
_ENTITIES: Tuple[Tuple[str, str, str, Dict[str, Any]], ...] = (
    ("binary_sensor", "state", "State",
     {"state_topic": "{state}", "value_template": "{{{{ value_json.state }}}}",
      "payload_on": "active", "payload_off": "inactive", "device_class": "connectivity"}),
    ("sensor", "last_seen", "Last seen",
     {"state_topic": "{state}", "value_template": "{{{{ value_json.last_seen }}}}",
      "device_class": "timestamp", "entity_category": "diagnostic"}),
    ("sensor", "last_message", "Last message",
     {"state_topic": "{rx}", "value_template": "{{{{ value_json.data }}}}", "json_attributes_topic": "{rx}",
      "icon": "mdi:message-text"}),
    ("sensor", "messages", "Messages received",
     {"state_topic": "{stats}", "value_template": "{{{{ value_json.nodes['{node}'].rx }}}}",
      "state_class": "total_increasing", "entity_category": "diagnostic"}),
    ("sensor", "errors", "Request errors",
     {"state_topic": "{stats}", "value_template": "{{{{ value_json.nodes['{node}'].errors }}}}",
      "state_class": "total_increasing", "entity_category": "diagnostic"}),
    ("sensor", "timeouts", "Timeouts",
     {"state_topic": "{stats}", "value_template": "{{{{ value_json.nodes['{node}'].timeouts }}}}",
      "state_class": "total_increasing", "entity_category": "diagnostic"}),
    ("sensor", "reply_time", "Reply time",
     {"state_topic": "{stats}", "value_template": "{{{{ value_json.nodes['{node}'].reply_ms }}}}",
      "unit_of_measurement": "ms", "device_class": "duration", "state_class": "measurement",
      "entity_category": "diagnostic"}),
    ("sensor", "bus_crc_errors", "Bus CRC errors",
     {"state_topic": "{stats}", "value_template": "{{{{ value_json.health.crc_errors | default(0) }}}}",
      "state_class": "total_increasing", "entity_category": "diagnostic"}),
)


#: entities only a request/reply protocol fills (a plug-in without them says REPLY_METRICS = False)
_REPLY_ENTITIES = frozenset({"errors", "timeouts", "reply_time"})


def _reply_metrics(bus: BusConfig) -> bool:
    """The bus's protocol measures requests and replies (FAP does not: its plug-in says so)."""
    return bool(getattr(_protocols.get(bus.protocol).plugin("bridge"), "REPLY_METRICS", True))


def slug(text: str) -> str:
    """``text`` as a discovery topic level / id part: [A-Za-z0-9_-] only."""
    if not isinstance(text, str):
        raise InvalidTypeError(f"slug needs a str, not {type(text).__name__}")
    return re.sub(r"[^A-Za-z0-9_-]", "_", text)


class Discovery:
    """Builds and publishes the discovery configurations of one bridge.

    Args:
        config: the bridge configuration (buses with ``homeassistant = true``).
        publish: ``publish(topic, payload)``, retained, outside the outbox.
    """

    def __init__(self, config: BridgeConfig, publish: Callable[[str, bytes], None]) -> None:
        if not isinstance(config, BridgeConfig) or not callable(publish):
            raise InvalidTypeError("Discovery(config: BridgeConfig, publish: callable)")
        self.config = config
        self.buses: Dict[str, BusConfig] = {b.name: b for b in config.buses if b.homeassistant}
        self._publish = publish
        self._lock = threading.Lock()
        self._nodes: Set[Tuple[str, int]] = set()
        self.status_topic = f"{config.discovery_prefix}/status"   # Home Assistant's birth message

    @property
    def enabled(self) -> bool:
        return bool(self.buses)

    def payloads(self, bus: str, node: int) -> List[Tuple[str, Dict[str, Any]]]:
        """(config topic, payload) of every entity of ``node``."""
        check_bus_node(bus, node)
        if bus not in self.buses:
            raise InvalidValueError(f"bus {bus[:40]!r} has no Home Assistant discovery")
        c, b = self.config, self.buses[bus]
        base = f"{c.prefix}/{bus}"
        topics = {"state": f"{base}/{node}/state", "rx": f"{base}/{node}/rx", "stats": f"{base}/stats"}
        dev_id = f"fap_{slug(c.host)}_{slug(bus)}_{node}"
        device = {"identifiers": [dev_id], "name": f"{bus} node {node}", "manufacturer": "fap_py",
                  "model": f"{b.protocol} {'slave' if b.role == 'slave' else 'node'} on {b.port}",
                  "via_device": f"fap_bridge_{slug(c.host)}"}
        availability = [{"topic": f"{c.prefix}/bridge/{c.host}/status",
                         "payload_available": "online", "payload_not_available": "offline"}]
        out = []
        replies = _reply_metrics(b)
        for component, key, name, fields in _ENTITIES:
            if key in _REPLY_ENTITIES and not replies:
                continue   # never filled for this protocol: no entity that stays "unknown"
            doc: Dict[str, Any] = {k: v.format(node=node, **topics) for k, v in fields.items()}
            doc.update(name=name, unique_id=f"{dev_id}_{key}", device=device, availability=availability,
                       qos=c.qos, origin=_ORIGIN)
            out.append((f"{c.discovery_prefix}/{component}/{dev_id}/{key}/config", doc))
        return out

    def bridge_payload(self) -> Tuple[str, Dict[str, Any]]:
        """The bridge's own device (the nodes' ``via_device``): its connectivity."""
        c = self.config
        dev_id = f"fap_bridge_{slug(c.host)}"
        doc = {"name": "Broker link", "unique_id": f"{dev_id}_status",
               "state_topic": f"{c.prefix}/bridge/{c.host}/status", "payload_on": "online",
               "payload_off": "offline", "device_class": "connectivity", "qos": c.qos,
               "device": {"identifiers": [dev_id], "name": f"fap bridge {c.host}", "manufacturer": "fap_py",
                          "model": "fap bridge"}, "origin": _ORIGIN}
        return f"{c.discovery_prefix}/binary_sensor/{dev_id}/status/config", doc

    def _send(self, bus: str, node: int) -> None:
        for topic, doc in self.payloads(bus, node):
            self._publish(topic, json.dumps(doc, separators=(",", ":")).encode())

    def node_seen(self, bus: str, node: int) -> None:
        """A node is known (configured or heard): announce it the first time."""
        check_bus_node(bus, node)
        if bus not in self.buses:
            return
        with self._lock:
            if (bus, node) in self._nodes:
                return
            self._nodes.add((bus, node))
        self._send(bus, node)

    def add_configured(self, nodes: Dict[str, Tuple[int, ...]]) -> None:
        """The nodes the configuration names, announced at the next :meth:`republish`."""
        if not isinstance(nodes, dict):
            raise InvalidTypeError(f"nodes must be a dict of bus: node numbers, not {type(nodes).__name__}")
        for bus, ids in nodes.items():
            if not isinstance(ids, (tuple, list)):
                raise InvalidTypeError(f"nodes[{bus!r:.40}] must be a tuple of node numbers")
            for n in ids:
                check_bus_node(bus, n)
        with self._lock:
            for bus, ids in nodes.items():
                if bus in self.buses:
                    self._nodes.update((bus, n) for n in ids)

    def republish(self) -> None:
        """Every known node again: after a (re)connect or Home Assistant's birth message."""
        with self._lock:
            nodes = sorted(self._nodes)
        topic, doc = self.bridge_payload()
        self._publish(topic, json.dumps(doc, separators=(",", ":")).encode())
        for bus, node in nodes:
            self._send(bus, node)


__all__ = ["Discovery", "slug"]
