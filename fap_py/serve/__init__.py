"""``fap serve``: one daemon owns a bus, every program shares it (docs/daemon.md).

The daemon opens the port (flock, TIOCEXCL and a UUCP lock file naming its
pid), runs the protocol's own engine and serves clients on Unix sockets and
TCP. Each client transaction (exec: request, reply, retries; mikroC: send and
reply; raw: request bytes and a reply rule) is atomic; clients share the bus
by wire time (deficit round-robin, per-client weight and priority, bounded
queues). Clients reach it by URL: ``fapd:///run/fap/bus0.sock`` or
``fapd://host:port``, accepted wherever a port path is (``fap_py.execasync.Master``,
``fap_py.mikroc.Master``, ``fap exec ... --port fapd://...``).

>>> from fap_py.serve import ServeConfig, run            # doctest: +SKIP
>>> run(ServeConfig("exec", "/dev/ttyUSB0", ["unix:/run/fap/bus0.sock"]))   # doctest: +SKIP
"""
from __future__ import annotations

from typing import Any, Dict, Optional

from ._client import TOKEN_ENV, Connection
from ._daemon import Daemon, ServeConfig, run
from ._errors import (
    BadUrlError,
    ClientQueueFullError,
    DaemonError,
    DaemonGoneError,
    DaemonRefusedError,
    ProtocolError,
)
from ._url import is_daemon_url
from ._wire import MAX_MESSAGE, VERSION

PROTOCOL_VERSION = VERSION


def status(url: Any, *, token: Optional[str] = None) -> Dict[str, Any]:
    """The daemon's status (clients, queue depths, share of wire time, late replies,
    errors, engine counters) as a dict: what ``fap serve status URL --json`` prints."""
    with Connection(url, token=token, name="status") as conn:
        return conn.call("status")["status"]


# the public names are this package's (the walk, pickling and help() name them so)
for _obj in (Connection, Daemon, ServeConfig, run, is_daemon_url, BadUrlError, ClientQueueFullError,
             DaemonError, DaemonGoneError, DaemonRefusedError, ProtocolError):
    _obj.__module__ = __name__
del _obj

__all__ = ["BadUrlError", "ClientQueueFullError", "Connection", "Daemon",
           "DaemonError", "DaemonGoneError", "DaemonRefusedError", "MAX_MESSAGE",
           "PROTOCOL_VERSION", "ProtocolError", "ServeConfig", "TOKEN_ENV", "is_daemon_url",
           "run", "status"]
