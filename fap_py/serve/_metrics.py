"""The daemon's Prometheus endpoint: ``GET /metrics`` in the text exposition format
(version 0.0.4), from the same figures as ``status``. Private.

The bridge's collector (``fap_py.bridge.metrics``) is built around the bridge's buses,
broker link and outbox, so it does not fit; this is the format written directly, on
the daemon's own loop (no thread): one short request per connection, bounded in size
and time.
"""
from __future__ import annotations

import asyncio
import logging
from typing import Any, Callable, Dict, List

log = logging.getLogger("fap_py.serve")

#: the longest request head read, bytes, and how long a scraper may take to send it
MAX_REQUEST = 8192
REQUEST_TIMEOUT = 5.0

_TOTALS = (("transactions", "Transactions run on the bus."),
           ("errors", "Transactions that failed (no reply, bad frame, port error ...)."),
           ("late", "Replies that came after their client's timeout (delivered to nobody)."),
           ("dropped", "Answers whose client had left."),
           ("queue_full", "Requests refused: the client's queue was full."),
           ("refused", "Connections refused (token, version, too many clients)."),
           ("cut_off", "Clients cut off (garbage, half-sent or oversized messages, not reading)."),
           ("port_gone", "Times the device vanished."),
           ("reopens", "Times the device was opened again."))


def _label(value: Any) -> str:
    return str(value).replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


def render(st: Dict[str, Any]) -> str:
    """The exposition text of one ``status()``."""
    d, t = st["daemon"], st["totals"]
    base = f'port="{_label(d["port"])}",protocol="{_label(d["protocol"])}"'
    out: List[str] = []

    def metric(name: str, kind: str, text: str, rows: List[str]) -> None:
        out.append(f"# HELP {name} {text}")
        out.append(f"# TYPE {name} {kind}")
        out.extend(rows)

    for key, text in _TOTALS:
        metric(f"fap_serve_{key}_total", "counter", text, [f"fap_serve_{key}_total{{{base}}} {t[key]}"])
    metric("fap_serve_wire_seconds_total", "counter", "Bus time used by transactions, seconds.",
           [f"fap_serve_wire_seconds_total{{{base}}} {d['wire_time']}"])
    metric("fap_serve_clients", "gauge", "Connected clients.", [f"fap_serve_clients{{{base}}} {t['clients']}"])
    metric("fap_serve_queued", "gauge", "Requests waiting for the bus.", [f"fap_serve_queued{{{base}}} {t['queued']}"])
    metric("fap_serve_port_up", "gauge", "1 while the device is open.",
           [f"fap_serve_port_up{{{base}}} {1 if d['port_state'] == 'open' else 0}"])
    per = [(c, f'{base},client="{c["client"]}",name="{_label(c["name"])}"') for c in st["clients"]]
    metric("fap_serve_client_wire_seconds_total", "counter", "Bus time used by one client, seconds.",
           [f"fap_serve_client_wire_seconds_total{{{lb}}} {c['wire_time']}" for c, lb in per])
    metric("fap_serve_client_transactions_total", "counter", "Transactions of one client.",
           [f"fap_serve_client_transactions_total{{{lb}}} {c['transactions']}" for c, lb in per])
    metric("fap_serve_client_late_total", "counter", "Late replies to one client's requests.",
           [f"fap_serve_client_late_total{{{lb}}} {c['late']}" for c, lb in per])
    metric("fap_serve_client_queued", "gauge", "Requests of one client waiting for the bus.",
           [f"fap_serve_client_queued{{{lb}}} {c['queued']}" for c, lb in per])
    return "\n".join(out) + "\n"


async def serve_metrics(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                        status: Callable[[], Dict[str, Any]]) -> None:
    """One scrape: ``GET /metrics`` -> 200 and the text; anything else 404 / 400."""
    try:
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), REQUEST_TIMEOUT)
    except (asyncio.TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError):
        writer.close()
        return
    parts = head.split(b"\r\n", 1)[0].split()
    if len(parts) != 3 or parts[0] != b"GET":
        code, body, ctype = "400 Bad Request", b"bad request\n", "text/plain"
    elif parts[1].split(b"?")[0] != b"/metrics":
        code, body, ctype = "404 Not Found", b"try /metrics\n", "text/plain"
    else:
        code, body, ctype = "200 OK", render(status()).encode(), "text/plain; version=0.0.4; charset=utf-8"
    writer.write(f"HTTP/1.1 {code}\r\nContent-Type: {ctype}\r\nContent-Length: {len(body)}\r\n"
                 "Connection: close\r\n\r\n".encode() + body)
    try:
        await asyncio.wait_for(writer.drain(), REQUEST_TIMEOUT)
    except (asyncio.TimeoutError, ConnectionError):
        pass
    writer.close()
