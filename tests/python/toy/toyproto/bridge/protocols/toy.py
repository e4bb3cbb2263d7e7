"""The toy protocol's bridge plug-in: a master polling ``nodes`` with ``poll_data`` on the
toy binding's Master. Everything the bridge needs of the toy is here; fap_py is not edited."""
from __future__ import annotations

from fap_py.bridge.buses import TxError
from fap_py.bridge.polled import PolledAdapter
from fap_py.bridge.polled import PolledOptions as Options
from fap_py.bridge.polled import polled_options as options

__all__ = ["ROLES", "DEFAULT_TIMEOUT", "Options", "options", "Adapter"]

ROLES = ("master",)
DEFAULT_TIMEOUT = 0.2   #: how long a request waits for its reply


class Adapter(PolledAdapter):
    """toyproto.binding.Master: one request, one reply."""

    HEALTH = {"frames_rx": ("frames_rx",), "frames_tx": ("frames_tx",), "crc_errors": ("rejected",),
              "timeouts": ("timeouts",)}

    def open(self) -> None:
        from toyproto.binding import Master

        c = self.cfg
        self.engine = Master(c.port, c.baud, timeout=c.timeout)

    def _request(self, node: int, data: bytes) -> bytes:
        reply: bytes = self.engine.request(node, data)
        return reply

    def _broadcast(self, data: bytes) -> None:   # never called: the toy has no broadcast address
        raise TxError("the toy protocol has no broadcast")
