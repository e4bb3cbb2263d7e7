"""The bridge's exec async plug-in: a master on fap_py.execasync's engine that polls
``nodes`` with ``poll_data`` (fap_py.bridge.polled)."""
from __future__ import annotations

from ..polled import PolledAdapter
from ..polled import PolledOptions as Options
from ..polled import polled_options as options

__all__ = ["ROLES", "DEFAULT_TIMEOUT", "Options", "options", "Adapter"]

ROLES = ("master",)
DEFAULT_TIMEOUT = 0.1   #: per transaction attempt


class Adapter(PolledAdapter):
    """fap_py.execasync.Master (its own retries and sequence numbers)."""

    HEALTH = {"frames_rx": ("rx_frames",), "frames_tx": ("tx_frames",), "crc_errors": ("corrupt",),
              "timeouts": ("timeouts",), "retries": ("retries",)}

    def open(self) -> None:
        from ...execasync import Master

        c = self.cfg
        self.engine = Master(c.port, c.baud, timeout=c.timeout, retries=c.retries, rs485=c.rs485)

    def _request(self, node: int, data: bytes) -> bytes:
        reply: bytes = self.engine.transact(node, data)
        return reply

    def _broadcast(self, data: bytes) -> None:
        self.engine.broadcast(data)
