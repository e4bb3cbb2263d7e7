"""Output ``sparkplug``: the bridge as a Sparkplug B edge node (``[sparkplug]``); the
edge node itself (its connection, births, seq and bdSeq) is
:class:`fap_py.bridge.sparkplug.SparkplugNode`, this file says what goes in it."""
from __future__ import annotations

from typing import Any, List, Optional

from ...errors import InvalidTypeError
from ..config import BridgeConfig
from ..sparkplug import BOOLEAN, BYTES, DOUBLE, STRING, UINT64, Metric, SparkplugNode
from ._base import RX, STATE, BridgeView, NodeEvent, NodeView, OutputBase


def _node_metrics(view: NodeView, fields: Optional[Any] = None) -> List[Metric]:
    """A node's Sparkplug metrics: its last message (if any) and its counters."""
    out: List[Metric] = []
    if fields is not None and isinstance(fields.get("data"), str):
        out.append(("data", BYTES, bytes.fromhex(fields["data"])))
    last = view.last_reply
    out += [("rx", UINT64, view.rx), ("tx", UINT64, view.tx), ("errors", UINT64, view.errors),
            ("timeouts", UINT64, view.timeouts),
            ("reply_ms", DOUBLE, None if last is None else last * 1000)]
    return out


class _SparkplugOutput(OutputBase):
    """Each node of a bus with ``sparkplug = true`` a device: DBIRTH/DDEATH when it
    becomes active/inactive, DDATA per message; NDATA with the bridge's own metrics
    every ``stats_interval``."""

    name = "sparkplug"

    def __init__(self, config: BridgeConfig) -> None:
        self.config = config
        self._ctx: Optional[BridgeView] = None
        self.node = SparkplugNode(config, self._bridge_metrics)   # its own MQTT connection

    def _bridge_metrics(self) -> List[Metric]:
        ctx = self._ctx
        assert ctx is not None   # births need a connection, made by start()
        return [("Bridge/Host", STRING, self.config.host), ("Bridge/Outbox rows", UINT64, ctx.store.pending),
                ("Bridge/Not stored", UINT64, ctx.not_stored),
                ("Bridge/MQTT refused", UINT64, ctx.link.refused_total),
                ("Bridge/MQTT connected", BOOLEAN, ctx.link.connected),
                ("Bridge/Invalid commands", UINT64, self.node.invalid_commands),
                ("Bridge/STATE refused", UINT64, sum(self.node.state_refused.values())),
                ("Bridge/Held dropped", UINT64, self.node.queue_dropped)]

    # what the metrics output reads (fap_bridge_sparkplug_*)
    @property
    def invalid_commands(self) -> int:
        return self.node.invalid_commands

    @property
    def rebirths(self) -> Any:
        return self.node.rebirths

    @property
    def births(self) -> int:
        return self.node.births

    @property
    def state_refused(self) -> Any:
        return dict(self.node.state_refused)

    @property
    def queue_dropped(self) -> int:
        return self.node.queue_dropped

    def on_connect(self, link: Any) -> None:
        # the edge node's own connection goes where the main link went (failover, failback)
        self.node.follow(link.broker)

    def start(self, ctx: BridgeView) -> None:
        self._ctx = ctx
        self.node.start()

    def on_node_event(self, view: NodeView, event: NodeEvent) -> None:
        if event.kind == RX:
            self.node.device(event.bus, event.node, _node_metrics(view, event.fields))
        elif event.kind == STATE:
            self.node.device(event.bus, event.node, [("active", BOOLEAN, event.active), *_node_metrics(view)],
                             alive=event.active)

    def on_tick(self) -> None:
        self.node.node_data()

    def stop(self) -> None:
        self.node.stop()


def create(config: BridgeConfig) -> Optional[_SparkplugOutput]:
    if not isinstance(config, BridgeConfig):
        raise InvalidTypeError(f"config must be a BridgeConfig, not {type(config).__name__}")
    return _SparkplugOutput(config) if config.sparkplug is not None else None


__all__ = ["create"]
