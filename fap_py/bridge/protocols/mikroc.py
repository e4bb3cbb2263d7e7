"""The bridge's mikroC plug-in: a master on fap_py.mikroc's engine that polls ``nodes``
with ``poll_data`` (fap_py.bridge.polled)."""
from __future__ import annotations

from ..polled import PolledAdapter
from ..polled import PolledOptions as Options
from ..polled import polled_options as options

__all__ = ["ROLES", "DEFAULT_TIMEOUT", "Options", "options", "Adapter"]

ROLES = ("master",)
DEFAULT_TIMEOUT = 0.1   #: how long a request waits for its reply


class Adapter(PolledAdapter):
    """fap_py.mikroc.Master: one request, one reply (no retries of its own)."""

    HEALTH = {"frames_rx": ("frames",), "crc_errors": ("damaged",)}

    def open(self) -> None:
        from ...mikroc import Master

        c = self.cfg
        self.engine = Master(c.port, c.baud, rs485=c.rs485)

    def _request(self, node: int, data: bytes) -> bytes:
        reply: bytes = self.engine.request(node, data, timeout=self.cfg.timeout).data
        return reply

    def _broadcast(self, data: bytes) -> None:
        self.engine.send(self.proto.broadcast, data)
