"""systemd's notify protocol, spoken directly: one datagram per message to $NOTIFY_SOCKET.

``Type=notify`` units wait for ``READY=1``; ``WatchdogSec=`` expects
``WATCHDOG=1`` at least every ``$WATCHDOG_USEC`` microseconds (we send at
half that). Outside systemd (no ``NOTIFY_SOCKET``) every call does nothing.
No dependency: the protocol is a text datagram on an AF_UNIX socket
(sd_notify(3)); a name starting with ``@`` is in the abstract namespace.
"""
from __future__ import annotations

import logging
import os
import socket
from typing import Mapping, Optional

from ..errors import InvalidTypeError

log = logging.getLogger(__name__)


class Notifier:
    """Sends to ``$NOTIFY_SOCKET`` (taken from ``env`` at construction)."""

    def __init__(self, env: Optional[Mapping[str, str]] = None) -> None:
        env = os.environ if env is None else env
        if not isinstance(env, Mapping):
            raise InvalidTypeError(f"env must be a mapping of str, not {type(env).__name__}")
        path = env.get("NOTIFY_SOCKET", "")
        if not all(isinstance(v, str) for v in (path, env.get("WATCHDOG_USEC", ""),
                                                  env.get("WATCHDOG_PID", ""))):
            raise InvalidTypeError("env: NOTIFY_SOCKET, WATCHDOG_USEC and WATCHDOG_PID must be str")
        self.address: Optional[str] = None
        if path.startswith("@"):
            self.address = "\0" + path[1:]
        elif path.startswith("/"):
            self.address = path
        self.watchdog: Optional[float] = None   #: seconds between pings, None: no watchdog
        usec, pid = env.get("WATCHDOG_USEC", ""), env.get("WATCHDOG_PID", "")
        if self.address and usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid())):
            self.watchdog = int(usec) / 2e6
        self._sock: Optional[socket.socket] = None
        if self.address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, **fields: object) -> bool:
        """``notify(READY=1, STATUS="...")``: one datagram; False if it could not be sent."""
        if self._sock is None or self.address is None:
            return False
        text = "\n".join(f"{k}={str(v).replace(chr(10), ' ')}" for k, v in fields.items())
        try:
            self._sock.sendto(text.encode(), self.address)
        except OSError as exc:   # systemd gone or the socket full: never fatal to the bridge
            log.debug("sd_notify %s: %s", text.split("\n")[0], exc)
            return False
        return True

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


__all__ = ["Notifier"]
