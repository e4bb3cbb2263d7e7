"""The mikroC master on a port (the C master)."""
from __future__ import annotations

import logging
from typing import Any, Optional

from .._native import lib
from ..errors import FrameError, error_from_code
from ..rs485 import RS485
from .codec import DEFAULT_BAUD, Message, _check_address, _check_data
from .daemon import DaemonMaster
from .node import PathLike, _Node

__all__ = ["Master"]

log = logging.getLogger(__name__)


class Master(_Node):
    """A mikroC master on a serial port: ``send`` to a slave, ``receive`` its
    reply. Runs the C master (``mikrocRS485_CtxInitMaster``). ``port_path`` may be a
    daemon's ``fapd://`` URL (``fap serve --protocol mikroc``): a
    :class:`DaemonMaster` is returned."""

    def __new__(cls, port_path: Any = None, *args: Any, **kwargs: Any) -> Any:
        from ..serve._url import is_daemon_url

        if cls is Master and is_daemon_url(port_path):
            return DaemonMaster(port_path, *args, **kwargs)
        return super().__new__(cls)

    def __init__(self, port_path: PathLike, baudrate: int = DEFAULT_BAUD, *,
                 rs485: Optional[RS485] = None) -> None:
        """Open ``port_path``. ``rs485`` holds the line options (direction
        mode, RTS, echo suppression, turnaround: :class:`fap_py.RS485`,
        the same for every protocol); ``None`` = the port layer's defaults."""
        super().__init__(port_path, baudrate, rs485)

    def _init_ctx(self) -> None:
        lib.mikrocRS485_CtxInitMaster(self._ctx)

    def send(self, address: int, data: bytes = b"") -> None:
        """Send 0..3 bytes to slave ``address`` (50 = broadcast). Input that
        arrived before (a late reply to an earlier request, a half frame) is
        discarded first, so the next ``receive`` returns a reply to this
        (not when a receive() is already running in another thread)."""
        _check_address(address)
        data = _check_data(data)
        # Skipped while another thread already waits in receive(): that
        # thread owns the receive side, and what it gets is its business.
        if self._lock.acquire(blocking=False):
            try:
                r = self._call(lambda _h: lib.mikrocRS485_CtxResetRx(self._ctx))
            finally:
                self._lock.release()
            if r < 0:
                raise error_from_code(r, "flush", self.path)
        if log.isEnabledFor(logging.DEBUG):
            log.debug("%s: tx to %d %s", self.path, address, data.hex())
        self._send(data, address)

    def receive(self, timeout: Optional[float] = 1.0) -> Message:
        """The next frame from a slave: Message(address=slave, data).
        Raises FapTimeoutError, or a MikrocFrameError subclass for a damaged
        frame."""
        return self._receive(timeout, from_master=False)

    async def areceive(self, timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`receive`: the port fd drives it (``loop.add_reader``, no thread)."""
        return await self._areceive(timeout, from_master=False)

    async def arequest(self, address: int, data: bytes = b"",
                       timeout: Optional[float] = 1.0) -> Message:
        """``await``-able :meth:`request` (the send itself does not wait for the bus)."""
        self.send(address, data)
        reply = await self.areceive(timeout)
        if reply.address != address:
            raise FrameError(f"reply from slave {reply.address}, expected {address}")
        return reply

    def request(self, address: int, data: bytes = b"", timeout: Optional[float] = 1.0) -> Message:
        """``send`` then ``receive``; the reply must come from ``address``."""
        self.send(address, data)
        reply = self.receive(timeout)
        if reply.address != address:
            raise FrameError(f"reply from slave {reply.address}, expected {address}")
        return reply
