"""The HTTP side of ``fap web``: aiohttp routes, the SSE stream, access rules.

Endpoints (docs/web.md): ``/`` the page, ``/static/*`` its assets, and under
``/api/``: ``info``, ``stream`` (Server-Sent Events), ``stats``, ``frames``,
``download.pcap``, ``download.jsonl``, ``export.html``, ``faults``, ``clients``.
"""
from __future__ import annotations

import asyncio
import hmac
import io
import json
import logging
import os
from typing import Any, Awaitable, Callable, Dict, List, Optional

from aiohttp import web

from ..errors import FapError
from ..monitor.pcap import PcapWriter
from ._access import host_name, is_loopback
from ._hub import Entry, Hub
from ._sources import Source

log = logging.getLogger("fap_py.web")

STATIC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")
ASSETS = {"index.html": "text/html", "app.js": "text/javascript", "style.css": "text/css"}
#: frames per SSE message, and the backlog a new page starts with
BATCH = 500
BACKLOG = 2000
#: how often the page gets the node table and the plots' series, seconds
STATS_EVERY_S = 0.1   # the node table within 250 ms of a frame (bench/web/bench_web.py)
#: a browser that takes longer than this for one write is cut off (it reconnects)
WRITE_TIMEOUT_S = 10.0
#: SSE streams at once; more get 503
MAX_STREAMS = 32
#: the largest request body (a fault request is a few dozen bytes)
MAX_BODY = 16 * 1024
#: frames in a self-contained export at most, and its node-table steps (the slider)
EXPORT_FRAMES = 50000
EXPORT_STEPS = 50

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def _error(status: int, text: str) -> web.Response:
    return web.json_response({"ok": False, "error": text}, status=status)


def envelope(e: Entry) -> str:
    """One frame on the stream: ``frame`` is exactly the record's ``fap monitor --json`` line."""
    return (f'{{"seq":{e.seq},"node":{json.dumps(e.node)},"role":{json.dumps(e.role)},'
            f'"frame":{e.line}}}')


class App:
    """The aiohttp application over one source and its hub."""

    def __init__(self, source: Source, hub: Hub, token: Optional[str], host: str) -> None:
        self.source, self.hub, self.token, self.host = source, hub, token, host
        self.streams = 0
        self.app = web.Application(client_max_size=MAX_BODY, middlewares=[self._guard])
        r = self.app.router
        r.add_get("/", self._page)
        r.add_get("/static/{name}", self._asset)
        r.add_get("/api/info", self._info)
        r.add_get("/api/stream", self._stream)
        r.add_get("/api/stats", self._stats)
        r.add_get("/api/frames", self._frames)
        r.add_get("/api/download.pcap", self._pcap)
        r.add_get("/api/download.jsonl", self._jsonl)
        r.add_get("/api/export.html", self._export)
        r.add_get("/api/faults", self._faults)
        r.add_get("/api/clients", self._clients)
        r.add_post("/api/faults", self._fault_add)
        r.add_delete("/api/faults/{id}", self._fault_remove)

    # -- access ---------------------------------------------------------------
    @web.middleware
    async def _guard(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Loopback without a token: any local page, but the Host must be a loopback name
        (no DNS rebinding). With a token: every /api/ request carries it, control ones too."""
        host = host_name(request.host or "")
        if self.token is None and not is_loopback(host):
            return _error(403, "Host is not a loopback address (run with --token to serve others)")
        if request.path.startswith("/api/") and self.token is not None:
            given = request.query.get("token", "")
            auth = request.headers.get("Authorization", "")
            if auth.startswith("Bearer "):
                given = auth[7:]
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return _error(401, "missing or wrong token (?token= or Authorization: Bearer)")
        if request.method == "POST" and request.content_type != "application/json":
            # a form post from another site cannot set this type without a CORS preflight
            return _error(415, "a control request is application/json")
        return await handler(request)

    # -- the page -------------------------------------------------------------
    async def _page(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(os.path.join(STATIC, "index.html"),
                                headers={"Content-Type": "text/html; charset=utf-8",
                                         "Cache-Control": "no-cache"})

    async def _asset(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if name not in ASSETS:
            return _error(404, "no such asset")
        return web.FileResponse(os.path.join(STATIC, name),
                                headers={"Content-Type": f"{ASSETS[name]}; charset=utf-8",
                                         "Cache-Control": "no-cache"})

    async def _info(self, request: web.Request) -> web.StreamResponse:
        from .. import __version__

        return web.json_response({**self.source.describe(), "version": __version__,
                                  "token": self.token is not None, "ring": self.hub.capacity})

    # -- the stream -----------------------------------------------------------
    async def _stream(self, request: web.Request) -> web.StreamResponse:
        if self.streams >= MAX_STREAMS:
            return _error(503, f"too many streams ({MAX_STREAMS})")
        try:
            backlog = max(0, min(int(request.query.get("backlog", BACKLOG)), self.hub.capacity))
        except ValueError:
            return _error(400, "backlog must be a whole number")
        resp = web.StreamResponse(headers={"Content-Type": "text/event-stream", "Cache-Control": "no-cache",
                                           "X-Accel-Buffering": "no"})
        self.streams += 1
        client = self.hub.connect(backlog)
        loop = asyncio.get_running_loop()
        try:
            await resp.prepare(request)
            await self._send(resp, "info", json.dumps(self.source.describe()))
            next_stats = 0.0
            while not self.hub.closing:
                entries, dropped = self.hub.read(client, BATCH)
                if dropped:
                    await self._send(resp, "dropped", json.dumps({"n": dropped, "total": client.dropped}))
                if entries:
                    await self._send(resp, "frames", "[" + ",".join(envelope(e) for e in entries) + "]")
                now = loop.time()
                if now >= next_stats:
                    next_stats = now + STATS_EVERY_S
                    snap = self.hub.snapshot()
                    snap["dropped"] = client.dropped
                    await self._send(resp, "stats", json.dumps(snap))
                if len(entries) == BATCH:
                    continue                  # more waiting: no sleep
                client.event.clear()
                try:
                    await asyncio.wait_for(client.event.wait(), max(0.01, next_stats - loop.time()))
                except asyncio.TimeoutError:
                    pass
        except (ConnectionError, asyncio.TimeoutError, asyncio.CancelledError):
            pass
        finally:
            self.streams -= 1
            self.hub.disconnect(client)
        return resp

    @staticmethod
    async def _send(resp: web.StreamResponse, event: str, data: str) -> None:
        await asyncio.wait_for(resp.write(f"event: {event}\ndata: {data}\n\n".encode()), WRITE_TIMEOUT_S)

    # -- windows of the ring --------------------------------------------------
    def _window(self, request: web.Request) -> List[Entry]:
        q = request.query
        try:
            bounds: Dict[str, Any] = {k: (int(q[k]) if k.startswith("seq") else float(q[k]))
                                      for k in ("seq0", "seq1", "t0", "t1") if k in q}
        except ValueError:
            raise web.HTTPBadRequest(text=json.dumps({"ok": False, "error": "seq0/seq1 are whole numbers, "
                                                      "t0/t1 seconds"}), content_type="application/json") from None
        return self.hub.window(**bounds)

    async def _stats(self, request: web.Request) -> web.StreamResponse:
        if not any(k in request.query for k in ("seq0", "seq1", "t0", "t1")):
            return web.json_response(self.hub.snapshot())
        entries = self._window(request)
        return web.json_response(self.hub.table_of(entries, self.source.baud, self.hub.table.bin_s))

    async def _frames(self, request: web.Request) -> web.StreamResponse:
        entries = self._window(request)
        try:
            limit = max(1, min(int(request.query.get("limit", 5000)), 50000))
        except ValueError:
            return _error(400, "limit must be a whole number")
        entries = entries[-limit:]
        return web.Response(text="[" + ",".join(envelope(e) for e in entries) + "]",
                            content_type="application/json")

    async def _pcap(self, request: web.Request) -> web.StreamResponse:
        entries = self._window(request)
        buf = io.BytesIO()
        w = PcapWriter(buf)
        for e in entries:
            if e.rec is not None:          # an MQTT source's messages are no wire frames
                w.write(e.rec)
        return web.Response(body=buf.getvalue(), content_type="application/vnd.tcpdump.pcap",
                            headers={"Content-Disposition": 'attachment; filename="fap-web.pcap"'})

    async def _jsonl(self, request: web.Request) -> web.StreamResponse:
        entries = self._window(request)
        return web.Response(body="".join(e.line + "\n" for e in entries).encode(),
                            content_type="application/x-ndjson",
                            headers={"Content-Disposition": 'attachment; filename="fap-web.jsonl"'})

    async def _export(self, request: web.Request) -> web.StreamResponse:
        entries = self._window(request)
        html = export_html(self.source, self.hub, entries)
        return web.Response(text=html, content_type="text/html",
                            headers={"Content-Disposition": 'attachment; filename="fap-web.html"'})

    # -- faults (a simulator) -------------------------------------------------
    async def _call(self, fn: Callable[..., Any], *args: Any) -> web.StreamResponse:
        loop = asyncio.get_running_loop()
        try:
            out = await loop.run_in_executor(None, fn, *args)
        except FapError as exc:
            return _error(400, str(exc))
        return web.json_response({"ok": True, "result": out})

    async def _faults(self, request: web.Request) -> web.StreamResponse:
        return await self._call(self.source.faults)

    async def _clients(self, request: web.Request) -> web.StreamResponse:
        return await self._call(self.source.clients)

    async def _fault_add(self, request: web.Request) -> web.StreamResponse:
        try:
            body = await request.json()
        except (ValueError, UnicodeDecodeError, RecursionError):
            return _error(400, "the body is not JSON")
        except web.HTTPRequestEntityTooLarge:
            return _error(413, f"the body is larger than {MAX_BODY} bytes")
        if not isinstance(body, dict):
            return _error(400, "a fault is a JSON object")
        return await self._call(self.source.add_fault, body)

    async def _fault_remove(self, request: web.Request) -> web.StreamResponse:
        text = request.match_info["id"]
        fid: Any = "all" if text == "all" else None
        if fid is None:
            try:
                fid = int(text)
            except ValueError:
                return _error(400, "a fault id is a whole number or all")
        return await self._call(self.source.remove_fault, fid)


def _read_asset(name: str) -> str:
    with open(os.path.join(STATIC, name), encoding="utf-8") as fh:
        return fh.read()


def _script_json(obj: Any) -> str:
    """JSON safe inside a <script> element."""
    return json.dumps(obj, separators=(",", ":")).replace("</", "<\\/").replace("<!--", "<\\!--")


def export_html(source: Source, hub: Hub, entries: List[Entry]) -> str:
    """One file, offline: the page, its script and style inlined, the frames and the node
    table at EXPORT_STEPS points of the recording embedded."""
    truncated = max(0, len(entries) - EXPORT_FRAMES)
    entries = entries[:EXPORT_FRAMES]
    times = [e.t for e in entries if e.t is not None]
    steps = []
    if times:
        t0, t1 = min(times), max(times)
        # entries in seq order are in time order (the monitor's times never go backwards)
        steps = hub.tables_until(entries, [t0 + (t1 - t0) * k / EXPORT_STEPS for k in range(1, EXPORT_STEPS + 1)],
                                 source.baud, hub.table.bin_s)
    data = {"info": {**source.describe(), "export": True, "truncated": truncated},
            "frames": [json.loads(envelope(e)) for e in entries], "steps": steps,
            "stats": hub.table_of(entries, source.baud, hub.table.bin_s)}
    page = _read_asset("index.html")
    page = page.replace('<link rel="stylesheet" href="static/style.css">',
                        "<style>\n" + _read_asset("style.css") + "\n</style>")
    page = page.replace('<script src="static/app.js"></script>',
                        '<script type="application/json" id="fap-export">' + _script_json(data) + "</script>\n"
                        "<script>\n" + _read_asset("app.js").replace("</script", "<\\/script") + "\n</script>")
    return page


__all__ = ["App", "envelope", "export_html"]
