"""The life cycle every daemon client class shares (``Master("fapd://...")`` of each
protocol, docs/daemon.md): close, aclose and both context managers, written once.

Private. A class sets ``_conn`` (the blocking :class:`fap_py.serve._client.Connection`)
and, if it has asyncio calls of its own, ``_aconn`` (a ``PerLoop``); ``_closed()`` is
its hook for what else a close ends. No import of the serve room here: the protocol
modules use this at import time, and the serve room imports them.
"""
from __future__ import annotations

from typing import Any, TypeVar

_T = TypeVar("_T", bound="DaemonLife")


class DaemonLife:
    """close() leaves the daemon (idempotent); aclose() also closes the asyncio
    connection in its own loop; ``with`` and ``async with`` close on the way out."""

    _conn: Any
    _aconn: Any = None

    def _closed(self) -> None:
        """What else a close ends (a class's own hooks); nothing by default."""

    def close(self) -> None:
        """Leave the daemon (idempotent)."""
        self._conn.close()
        if self._aconn is not None:
            self._aconn.abandon()
        self._closed()

    async def aclose(self) -> None:
        """:meth:`close` from a coroutine: the asyncio connection ends in its loop."""
        if self._aconn is not None:
            await self._aconn.close()
        self.close()

    def __enter__(self: _T) -> _T:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def __aenter__(self: _T) -> _T:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()
