"""The mikroC slave on a port (the C slave)."""
from __future__ import annotations

import logging
from typing import Optional

from .._native import lib
from ..rs485 import RS485
from .codec import DEFAULT_BAUD, Message, _check_address, _check_data
from .node import PathLike, _Node

__all__ = ["Slave"]

log = logging.getLogger(__name__)


class Slave(_Node):
    """A mikroC slave at ``address``: ``receive`` frames for it (and
    broadcasts), ``send`` replies. Runs the C slave."""

    _buffer_size = lib.MIKROC_RS485_SLAVE_BUFFER

    def __init__(self, port_path: PathLike, baudrate: int = DEFAULT_BAUD, address: int = 1, *,
                 rs485: Optional[RS485] = None) -> None:
        self.address = _check_address(address)
        super().__init__(port_path, baudrate, rs485)

    def _init_ctx(self) -> None:
        lib.mikrocRS485_CtxInitSlave(self._ctx, self.address)

    def _frame_address(self, raw: bytes) -> int:
        # own or BROADCAST: a slave's 6-byte buffer has no room for it, the C context keeps it
        return int(self._c_stats().last_address)

    def send(self, data: bytes = b"") -> None:
        """Reply with 0..3 bytes (from this slave's address)."""
        data = _check_data(data)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: tx from %d %s", self.path, self.address, data.hex())
        self._send(data, self.address)

    def receive(self, timeout: Optional[float] = 1.0) -> Message:
        """The next frame for this slave: Message(address=own or BROADCAST).
        Raises FapTimeoutError, or a MikrocFrameError subclass for a damaged
        frame addressed to it."""
        return self._receive(timeout, from_master=True)

    async def areceive(self, timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`receive`: the port fd drives it (``loop.add_reader``, no thread)."""
        return await self._areceive(timeout, from_master=True)

    def __repr__(self) -> str:
        return f"Slave({self.path!r}, address={self.address})"
