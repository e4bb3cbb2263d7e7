"""The interface every output of the bridge has (docs/bridge.md, "Outputs"); its names are
public in :mod:`fap_py.bridge.outputs`.

An output is what the bridge feeds besides its own topics: Home Assistant
discovery, a Sparkplug B edge node, a Prometheus endpoint, or one a user
adds. :class:`~fap_py.bridge.Bridge` knows outputs only through
:class:`Output`: it builds them by name (:mod:`fap_py.bridge.outputs`),
starts them with a :class:`BridgeView`, tells them of each (re)connect, of
each node event (with a read-only :class:`NodeView` of the node's
counters) and of messages on the topics they subscribe to, calls
``on_tick`` every ``stats_interval`` while connected, and stops them.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Dict, Iterable, Mapping, Optional, Protocol, Tuple, runtime_checkable

from ..._validate import check_bool, check_bytes, check_int
from ...errors import InvalidTypeError, InvalidValueError

#: the kinds of :class:`NodeEvent`
SEEN = "seen"     #: the node is known (each time its state is set, changed or not)
STATE = "state"   #: the node became active or inactive (``event.active``)
RX = "rx"         #: a message or register read received (``event.fields``)
EVENT_KINDS = (SEEN, STATE, RX)

#: MQTT's largest packet (its remaining length field): no payload is longer
PAYLOAD_MAX = 268_435_455
#: an MQTT topic is at most 65535 bytes of UTF-8
TOPIC_MAX = 65535


def _text(value: Any, what: str, limit: int = 200) -> str:
    """``value`` if it is a non-empty str without NUL of at most ``limit`` characters."""
    if not isinstance(value, str):
        raise InvalidTypeError(f"{what} must be a str, not {type(value).__name__}")
    if not value or "\0" in value or len(value) > limit:
        raise InvalidValueError(f"{what} must be a non-empty name without NUL of at most {limit} "
                                f"characters, not {value[:60]!r}")
    return value


def check_topic(topic: Any, what: str = "topic") -> str:
    """An MQTT topic to publish on: a non-empty str of at most 65535 UTF-8 bytes, no NUL and
    no wildcard (``+``, ``#``: a subscription's, never a publication's)."""
    if not isinstance(topic, str):
        raise InvalidTypeError(f"{what} must be a str, not {type(topic).__name__}")
    if not topic or "\0" in topic or "+" in topic or "#" in topic:
        raise InvalidValueError(f"{what} {topic[:80]!r}: an MQTT topic to publish on is non-empty "
                                "and has no NUL and no wildcard (+, #)")
    try:
        size = len(topic.encode("utf-8"))
    except UnicodeError:
        raise InvalidValueError(f"{what} {topic[:80]!r} is not valid UTF-8 (a lone surrogate)") from None
    if size > TOPIC_MAX:
        raise InvalidValueError(f"{what} is {size} bytes of UTF-8; an MQTT topic is at most {TOPIC_MAX}")
    return topic


@dataclass(frozen=True)
class NodeEvent:
    """What happened to a node: ``kind`` is one of :data:`EVENT_KINDS`."""

    kind: str
    bus: str
    node: int
    active: Optional[bool] = None                 #: STATE: the new state
    fields: Optional[Mapping[str, Any]] = None    #: RX: the received fields (read-only)


class NodeView:
    """A read-only view of one node's counters (read when asked, never copied)."""

    __slots__ = ("_adapter", "_node")
    _adapter: Any
    _node: int

    def __init__(self, adapter: Any, node: int) -> None:
        object.__setattr__(self, "_adapter", adapter)
        object.__setattr__(self, "_node", node)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("NodeView is read-only")

    @property
    def bus(self) -> str:
        return str(self._adapter.cfg.name)

    @property
    def node(self) -> int:
        return self._node

    @property
    def protocol(self) -> str:
        return str(self._adapter.cfg.protocol)

    def _c(self) -> Any:
        return self._adapter.node(self._node)

    @property
    def rx(self) -> int:
        return int(self._c().rx)

    @property
    def tx(self) -> int:
        return int(self._c().tx)

    @property
    def errors(self) -> int:
        return int(self._c().errors)

    @property
    def timeouts(self) -> int:
        return int(self._c().timeouts)

    @property
    def replies(self) -> int:
        return int(self._c().reply_count)

    @property
    def last_reply(self) -> Optional[float]:
        """Seconds of the last request-to-reply, None before the first."""
        return self._c().last_reply

    def report(self) -> Dict[str, Any]:
        """The counters as published in stats (a copy)."""
        return dict(self._c().report())


class BridgeView:
    """What an output may read of the bridge, and the one thing it may do: publish
    outside the outbox (``publish_now``). Attributes are read-only."""

    __slots__ = ("_bridge",)
    _bridge: Any

    def __init__(self, bridge: Any) -> None:
        object.__setattr__(self, "_bridge", bridge)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("BridgeView is read-only")

    @property
    def config(self) -> Any:
        return self._bridge.config

    @property
    def buses(self) -> Mapping[str, Any]:
        """Bus name -> its adapter (a read-only mapping)."""
        return MappingProxyType(self._bridge.buses)

    @property
    def link(self) -> Any:
        """The broker link (connected, counters)."""
        return self._bridge.link

    @property
    def store(self) -> Any:
        """The outbox (pending, dropped)."""
        return self._bridge.store

    @property
    def not_stored(self) -> int:
        return int(self._bridge.not_stored)

    @property
    def tx_refused(self) -> int:
        return int(self._bridge.tx_refused)

    @property
    def duplicates(self) -> int:
        return int(self._bridge.duplicates)

    def node_states(self) -> Dict[Tuple[str, int], bool]:
        return dict(self._bridge.node_states())

    def node(self, bus: str, node: int) -> NodeView:
        """The read-only counters of ``node`` (an address 0..255) on ``bus`` (a configured
        bus's name: :class:`~fap_py.errors.InvalidValueError` naming the known ones if not)."""
        _text(bus, "bus")
        node = check_int(node, "node", 0, 0xFF)     # one address byte, as the adapters count
        buses = self._bridge.buses
        if bus not in buses:
            raise InvalidValueError(f"no bus {bus[:60]!r} in this bridge (buses: "
                                    f"{', '.join(sorted(buses)) or 'none'})")
        return NodeView(buses[bus], node)

    def output(self, name: str) -> Optional["Output"]:
        """Another running output, by name (None if it is not configured)."""
        return self._bridge.outputs.get(_text(name, "name"))

    def publish_now(self, topic: str, payload: bytes, retain: bool = True) -> None:
        """Publish on the main connection, outside the outbox (QoS 1, best effort; nothing
        while the broker is not connected). ``topic``: :func:`check_topic`; ``payload``:
        bytes-like; ``retain``: a bool."""
        check_topic(topic)
        payload = check_bytes(payload, "payload", 0, PAYLOAD_MAX)
        check_bool(retain, "retain")
        self._bridge.link.publish_now(topic, payload, retain)


@runtime_checkable
class Output(Protocol):
    """One output. Every method is called by the bridge; none may block for long
    (``on_node_event`` runs on a bus's thread, ``on_message`` and ``on_connect`` on
    the broker link's). An exception in a hook is logged, and the bridge goes on."""

    name: str

    def subscriptions(self) -> Iterable[str]:
        """Topics (on the main connection) whose messages go to :meth:`on_message`."""
        ...

    def start(self, ctx: BridgeView) -> None:
        """Before the buses open; an exception stops the bridge's start."""
        ...

    def on_connect(self, link: Any) -> None:
        """The main broker link (re)connected."""
        ...

    def on_node_event(self, view: NodeView, event: NodeEvent) -> None: ...

    def on_message(self, topic: str, payload: bytes) -> None: ...

    def on_tick(self) -> None:
        """Every ``stats_interval`` while the broker is connected."""
        ...

    def stop(self) -> None:
        """Once the buses stopped (no more events), before the outbox drains."""
        ...


class OutputBase:
    """An :class:`Output` whose hooks do nothing: subclass and override what you need.

    The defaults check what they are handed as the bridge hands it (``start``: a
    :class:`BridgeView`; ``on_connect``: the broker link; ``on_node_event``: a
    :class:`NodeView` and a :class:`NodeEvent`; ``on_message``: a str topic and
    bytes), so a hook called by hand with something else raises
    :class:`~fap_py.errors.InvalidTypeError` rather than doing nothing."""

    name = "output"

    def subscriptions(self) -> Iterable[str]:
        return ()

    def start(self, ctx: BridgeView) -> None:
        if not isinstance(ctx, BridgeView):
            raise InvalidTypeError(f"ctx must be a BridgeView, not {type(ctx).__name__}")
        self.ctx = ctx

    def on_connect(self, link: Any) -> None:
        from ..mqtt import MqttLink  # here: the link module is not needed to define an output

        if not isinstance(link, MqttLink):
            raise InvalidTypeError(f"link must be the bridge's MqttLink, not {type(link).__name__}")

    def on_node_event(self, view: NodeView, event: NodeEvent) -> None:
        if not isinstance(view, NodeView):
            raise InvalidTypeError(f"view must be a NodeView, not {type(view).__name__}")
        if not isinstance(event, NodeEvent):
            raise InvalidTypeError(f"event must be a NodeEvent, not {type(event).__name__}")

    def on_message(self, topic: str, payload: bytes) -> None:
        if not isinstance(topic, str):
            raise InvalidTypeError(f"topic must be a str, not {type(topic).__name__}")
        check_bytes(payload, "payload", 0, PAYLOAD_MAX)

    def on_tick(self) -> None:
        pass

    def stop(self) -> None:
        pass


__all__ = ["BridgeView", "EVENT_KINDS", "NodeEvent", "NodeView", "Output", "OutputBase", "RX", "SEEN", "STATE"]
