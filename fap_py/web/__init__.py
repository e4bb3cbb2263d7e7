"""``fap web``: a live bus in a browser (docs/web.md).

One source (a live port, a simulator, a capture file) decoded by the monitor's
own decoders, a bounded ring between it and the browsers, and an aiohttp server
(the optional extra ``pip install 'fap_py[web]'``) with one static page::

    from fap_py.web import SimSource, WebServer
    with WebServer(SimSource("site.toml"), port=0) as srv:
        print(srv.url)                     # open it in a browser
        srv.wait()                         # until srv.close() or a source error

The server runs its event loop in a thread of its own and the source in
another: the caller's thread is free (a test drives the bus from it).
"""
from __future__ import annotations

import asyncio
import logging
import secrets
import threading
from typing import Any, Optional

from .._closing import Closing
from .._validate import check_int, check_seconds
from ..errors import ClosedError, FapError, InvalidTypeError, InvalidValueError
from ._access import is_loopback
from ._hub import Hub
from ._mqtt import MqttSource
from ._sources import (
    CaptureSource,
    DaemonSource,
    NoClientsError,
    NoFaultsError,
    PortSource,
    SimControlSource,
    SimSource,
    Source,
)

log = logging.getLogger("fap_py.web")

INSTALL_HINT = "fap web needs aiohttp: pip install 'fap_py[web]'"
#: frames the ring holds by default (a capture source holds all of its file, up to MAX_RING)
RING = 20000
MAX_RING = 2_000_000
DEFAULT_PORT = 8485


class MissingDependencyError(FapError):
    """aiohttp (the ``web`` extra) is not installed."""


class WebAccessError(InvalidValueError):
    """A server address other than loopback without a token, or a bad token."""


def aiohttp_module() -> Any:
    """aiohttp, or MissingDependencyError naming the extra."""
    try:
        import aiohttp
        import aiohttp.web
    except ImportError:
        raise MissingDependencyError(INSTALL_HINT) from None
    return aiohttp


def new_token() -> str:
    """A random token for ``--token`` (URL-safe)."""
    return secrets.token_urlsafe(18)


class WebServer(Closing):
    """``source`` served on ``host``:``port`` (0: a free port; :attr:`url` tells).

    ``token``: required on every /api/ request when given; an address other than
    loopback needs one (WebAccessError). ``ring``: frames kept between the source
    and the browsers (a capture: the whole file, up to MAX_RING).
    """

    def __init__(self, source: Source, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 token: Optional[str] = None, ring: Optional[int] = None) -> None:
        if not isinstance(source, Source):
            raise InvalidTypeError(f"source must be a fap_py.web Source, not {type(source).__name__}")
        if not isinstance(host, str) or not host or "\0" in host:
            raise InvalidTypeError(f"host must be an address (str), not {host!r}")
        check_int(port, "port", 0, 65535)
        if token is not None:
            if not isinstance(token, str):
                raise InvalidTypeError(f"token must be a str, not {type(token).__name__}")
            if len(token) < 8 or not token.isascii() or not token.isprintable() or " " in token:
                raise WebAccessError("a token is at least 8 printable ASCII characters, no spaces")
        if token is None and not is_loopback(host):
            raise WebAccessError(f"serving on {host} (not loopback) needs a token (--token, or "
                                 "FAP_WEB_TOKEN)")
        if ring is not None:
            check_int(ring, "ring", 1, MAX_RING)
        self.source, self.host, self.port, self.token = source, host, port, token
        self.hub = Hub(ring or (MAX_RING if source.seekable else RING))
        if source.seekable:
            self.hub.expire_s = None
        self.url: Optional[str] = None
        self._stop = threading.Event()
        self._done = threading.Event()
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._threads: list = []
        self._runner: Any = None
        self._started = False
        self._closed = False

    def start(self) -> "WebServer":
        """Open the source, listen, start both threads; errors (a busy port, a bad
        file, the address in use) raise here."""
        if self._closed:
            raise ClosedError("the web server is closed")
        if self._started:
            return self
        aiohttp_module()
        self._started = True
        self.source.open()
        try:
            ready = threading.Event()
            failure: list = []
            t = threading.Thread(target=self._serve, args=(ready, failure), name="fap-web http", daemon=True)
            t.start()
            self._threads.append(t)
            ready.wait()
            if failure:
                raise failure[0]
        except BaseException:
            self.close()
            raise
        s = threading.Thread(target=self._run_source, name="fap-web source", daemon=True)
        s.start()
        self._threads.append(s)
        return self

    def _serve(self, ready: threading.Event, failure: list) -> None:
        from aiohttp import web

        from ._server import App

        loop = self._loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        app = App(self.source, self.hub, self.token, self.host)
        try:
            runner = self._runner = web.AppRunner(app.app, handle_signals=False, access_log=None,
                                                       shutdown_timeout=1.0)
            loop.run_until_complete(runner.setup())
            site = web.TCPSite(runner, self.host, self.port, backlog=128)
            loop.run_until_complete(site.start())
            addr = runner.addresses[0]
            self.port = addr[1]
            shown = f"[{addr[0]}]" if ":" in addr[0] else addr[0]
            self.url = f"http://{shown}:{self.port}/"
            self.hub.loop = loop
        except OSError as exc:
            from ..errors import PortError

            failure.append(PortError(exc.errno or 98, f"http {self.host}:{self.port}: {exc.strerror or exc}"))
            ready.set()
            loop.run_until_complete(self._runner.cleanup() if self._runner else asyncio.sleep(0))
            loop.close()
            return
        ready.set()
        try:
            loop.run_forever()
        finally:
            self.hub.loop = None
            loop.run_until_complete(runner.cleanup())
            # a stream stuck in a write to a browser that stopped reading: cancelled, awaited
            left = asyncio.all_tasks(loop)
            for task in left:
                task.cancel()
            loop.run_until_complete(asyncio.gather(*left, return_exceptions=True))
            loop.close()

    def _run_source(self) -> None:
        try:
            self.source.run(self.hub, self._stop)
            self.hub.finished()
        except Exception as exc:       # shown on the page and logged; the server stays up
            log.error("source stopped: %s: %s", type(exc).__name__, exc)
            self.hub.finished(f"{type(exc).__name__}: {exc}")
        finally:
            self._done.set()

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Wait until :meth:`close` (another thread) or ``timeout``; True once closed."""
        if timeout is not None:
            timeout = check_seconds(timeout, "timeout")
        return self._stop.wait(timeout)

    def wait_source(self, timeout: float = 10.0) -> bool:
        """Wait until the source ended (a capture read, an error); False at the timeout."""
        return self._done.wait(check_seconds(timeout, "timeout"))

    def close(self) -> None:
        """Stop the source, the server and both threads; release the source. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        loop = self._loop
        self.hub.closing = True
        if loop is not None and loop.is_running():
            try:
                loop.call_soon_threadsafe(self.hub._wake_clients)
                loop.call_soon_threadsafe(loop.stop)
            except RuntimeError:        # the loop ended meanwhile
                pass
        for t in self._threads:
            t.join(10.0)
        self.source.close()


__all__ = ["CaptureSource", "DaemonSource", "NoClientsError", "DEFAULT_PORT", "INSTALL_HINT", "MissingDependencyError", "MqttSource", "NoFaultsError",
           "PortSource", "RING", "SimControlSource", "SimSource", "Source", "WebAccessError", "WebServer", "aiohttp_module",
           "new_token"]
