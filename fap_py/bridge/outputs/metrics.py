"""Output ``metrics``: the Prometheus endpoint of ``[metrics] listen`` (the collector and
the HTTP server are :mod:`fap_py.bridge.metrics`)."""
from __future__ import annotations

from typing import Any, Optional

from ...errors import InvalidTypeError
from ..config import BridgeConfig
from ._base import BridgeView, OutputBase


class _MetricsOutput(OutputBase):
    """Serves ``/metrics`` from its own thread; it reads the counters at scrape time
    through the :class:`~fap_py.bridge.outputs.base.BridgeView` and needs no event."""

    name = "metrics"

    def __init__(self, config: BridgeConfig) -> None:
        self.config = config
        self.server: Any = None   # the MetricsServer, once started

    def start(self, ctx: BridgeView) -> None:
        from ..metrics import MetricsServer

        assert self.config.metrics_listen is not None
        self.server = MetricsServer(ctx, *self.config.metrics_listen,
                                    sim_control=self.config.metrics_sim_control)

    @property
    def port(self) -> int:
        """The port it listens on (the one chosen, with port 0)."""
        return int(self.server.port)

    @property
    def clients(self) -> int:
        return int(self.server.clients)

    def stop(self) -> None:
        if self.server is not None:
            self.server.close()


def create(config: BridgeConfig) -> Optional[_MetricsOutput]:
    if not isinstance(config, BridgeConfig):
        raise InvalidTypeError(f"config must be a BridgeConfig, not {type(config).__name__}")
    return _MetricsOutput(config) if config.metrics_listen is not None else None


__all__ = ["create"]
