"""Output ``homeassistant``: MQTT discovery for the buses with ``homeassistant = true``
(the configurations are built by :mod:`fap_py.bridge.homeassistant`)."""
from __future__ import annotations

from typing import Any, Iterable, Optional

from ...errors import InvalidTypeError
from ..config import BridgeConfig
from ..homeassistant import Discovery
from ..ratelimit import Coalescer
from ._base import SEEN, BridgeView, NodeEvent, NodeView, OutputBase

#: seconds between two republications of the discovery configurations that Home Assistant's
#: "online" asks for; more "online" within them are coalesced into one at their end
HA_REPUBLISH_MIN = 30.0


class _HomeAssistantOutput(OutputBase):
    """Announces every known node; again on each connect and when Home Assistant
    says ``online`` on ``<discovery_prefix>/status`` (at most once per
    :data:`HA_REPUBLISH_MIN` s, coalesced)."""

    name = "homeassistant"

    def __init__(self, config: BridgeConfig) -> None:
        self.config = config
        self._ctx: Optional[BridgeView] = None
        self.discovery = Discovery(config, self._publish)
        self.republish = Coalescer(self.discovery.republish, HA_REPUBLISH_MIN,
                                   "Home Assistant discovery republication")

    def _publish(self, topic: str, payload: bytes) -> None:
        if self._ctx is not None:
            self._ctx.publish_now(topic, payload)

    def subscriptions(self) -> Iterable[str]:
        return (self.discovery.status_topic,)   # Home Assistant's birth message

    def start(self, ctx: BridgeView) -> None:
        self._ctx = ctx
        self.discovery.add_configured({n: b.configured_nodes() for n, b in ctx.buses.items()})

    def on_connect(self, link: Any) -> None:
        self.discovery.republish()

    def on_message(self, topic: str, payload: bytes) -> None:
        if payload.strip() == b"online":   # Home Assistant (re)started: it wants the configs again
            self.republish.request()      # at most once per HA_REPUBLISH_MIN s (coalesced)

    def on_node_event(self, view: NodeView, event: NodeEvent) -> None:
        if event.kind == SEEN:
            self.discovery.node_seen(event.bus, event.node)

    def stop(self) -> None:
        self.republish.close()


def create(config: BridgeConfig) -> Optional[_HomeAssistantOutput]:
    """The output, when a bus asks for discovery."""
    if not isinstance(config, BridgeConfig):
        raise InvalidTypeError(f"config must be a BridgeConfig, not {type(config).__name__}")
    return _HomeAssistantOutput(config) if any(b.homeassistant for b in config.buses) else None


__all__ = ["create"]
