"""The daemon's exceptions: subclasses of the one hierarchy (:mod:`fap_py.errors`). Private.

A daemon that cannot be reached, or that went away, is a port that cannot be
opened or that vanished (:class:`~fap_py.errors.PortError`: exit 3 on the
command line); a refusal (token, version) is a port error too: the bus cannot
be used. A full per-client queue is :class:`~fap_py.errors.QueueFullError`.
"""
from __future__ import annotations

import errno

from ..errors import InvalidValueError, PortError, PortGoneError, QueueFullError


class DaemonError(PortError):
    """The daemon behind a ``fapd://`` URL cannot be reached (no socket, refused)."""

    def __init__(self, message: str, url: str = "", err: int = errno.ECONNREFUSED) -> None:
        super().__init__(err, message, url or None)


class DaemonGoneError(DaemonError, PortGoneError):
    """The daemon closed the connection (it stopped, or cut this client off)."""

    def __init__(self, message: str, url: str = "") -> None:
        DaemonError.__init__(self, message, url, errno.ECONNRESET)


class DaemonRefusedError(DaemonError):
    """The daemon refused this client: a bad token, another major version, too many clients."""

    def __init__(self, message: str, url: str = "") -> None:
        DaemonError.__init__(self, message, url, errno.EACCES)


class ProtocolError(DaemonError):
    """A message broke the client protocol (docs/daemon.md): bad length, bad JSON, bad field."""

    def __init__(self, message: str, url: str = "") -> None:
        DaemonError.__init__(self, message, url, errno.EPROTO)


class ClientQueueFullError(QueueFullError):
    """This client's queue on the daemon is full (``--queue`` requests waiting)."""


class BadUrlError(DaemonError, InvalidValueError):
    """A ``fapd://`` URL that does not parse (or a query key the daemon does not know):
    a port that cannot be opened (exit 3), and a bad value."""

    def __init__(self, message: str, url: str = "") -> None:
        DaemonError.__init__(self, message, "", errno.EINVAL)   # the message names the URL
        self.url = url


__all__ = ["BadUrlError", "ClientQueueFullError", "DaemonError", "DaemonGoneError",
           "DaemonRefusedError", "ProtocolError"]
