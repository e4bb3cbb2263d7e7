"""``fap web``: a live bus in a browser (docs/web.md).

    fap web --sim site.toml
    fap web --port /dev/ttyUSB0 --baud 115200 --protocol exec
    fap web --capture bus.cap --http 127.0.0.1:8485
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from typing import Any, Tuple

from . import _options as opt

EXAMPLE = """\
fap web --sim site.toml                      # the sim's bus, faults switched from the page
fap web --sim unix:/tmp/sim.sock --tap bus.cap   # a running fap sim (its bus's virtual.capture)
fap web --port /dev/ttyUSB0 --baud 115200 --protocol exec
fap web --capture bus.cap                    # a recording, with a time slider
fap web --mqtt bridge.toml --bus line1       # a bus as a bridge publishes it
fap web --http 0.0.0.0:8485 --token SECRET --sim site.toml"""

DESCRIPTION = """\
Serve one page that shows a bus live: frames decoded by the monitor's decoders,
a node table, plots, downloads (pcap, JSON lines, a self-contained HTML export)
and, for a simulator, its faults switched per node. Needs aiohttp
(pip install 'fap_py[web]'). Loopback only unless a token is given (--token or
FAP_WEB_TOKEN). See docs/web.md.

exit: 0 stopped by SIGINT or SIGTERM (with the summary), 2 usage error
      (aiohttp missing included), 3 port, file or address error"""


def http_address(text: str) -> Tuple[str, int]:
    """argparse type of ``--http``: HOST:PORT (``[::1]:8485`` for IPv6)."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"--http takes HOST:PORT, not {text!r}")
    return host.strip("[]"), int(port)


def register(sub: argparse._SubParsersAction) -> None:
    from .monitor import _choice

    p = opt.add_command(sub, "web", help="a live bus in a browser: frames, nodes, plots, faults",
                        description=DESCRIPTION, example=EXAMPLE)
    p.add_argument("--http", type=http_address, default=("127.0.0.1", 8485), metavar="HOST:PORT",
                   help="where to serve (default 127.0.0.1:8485; port 0: a free one)")
    p.add_argument("--token", metavar="TOKEN", default=None,
                   help="required on every API request (default: $FAP_WEB_TOKEN); needed to serve "
                        "on an address other than loopback")
    src = p.add_argument_group("source (one of)")
    from fap_py.monitor.session import LIVE_BAUD

    opt.add_port_options(p, baud_default=None, port_required=False, rs485_default="none",
                         port_help="a live serial port or URL, opened receive-only",
                         baud_help=f"line rate: opens --port at it ({LIVE_BAUD} if not given); a "
                         "capture's own rate if not given")
    src.add_argument("--sim", metavar="CONFIG", help="run the simulator of this config here, or "
                     "unix:PATH: a running `fap sim --control unix:PATH` (with --tap); its faults are "
                     "switched from the page")
    src.add_argument("--tap", metavar="FILE", help="--sim unix:PATH: the capture its bus writes "
                     "(the config's virtual.capture), followed as it grows")
    src.add_argument("--bus", metavar="NAME", help="--sim, --mqtt: the bus shown (default the first)")
    src.add_argument("--capture", metavar="FILE", help="a virtual-bus capture (fap bus --capture)")
    src.add_argument("--mqtt", metavar="BRIDGE_CONFIG", help="a bus as a bridge publishes it: the "
                     "bridge's config (its broker, prefix, buses); messages and the bridge's node "
                     "counters, not wire frames")

    from fap_py.monitor.session import protocol_choice, protocol_choices

    p.add_argument("--protocol", type=_choice(protocol_choice), choices=protocol_choices(),
                   default=None, help="decoder (default: the sim bus's protocol, else auto)")
    p.add_argument("--ring", type=opt.positive, default=None, metavar="N",
                   help="frames kept between the source and the browsers (default 20000; a "
                        "capture: all of it)")
    opt.add_output_options(p)
    p.set_defaults(func=run)


def _source(args: argparse.Namespace) -> Any:
    from fap_py import web

    given = [n for n in ("port", "sim", "capture", "mqtt") if getattr(args, n)]
    if len(given) != 1:
        raise opt.UsageError("give one source: --port, --sim, --capture or --mqtt"
                             + (f", not {' and '.join('--' + n for n in given)}" if given else ""))
    if args.bus and not (args.sim or args.mqtt):
        raise opt.UsageError("--bus needs --sim or --mqtt")
    remote = bool(args.sim and args.sim.startswith("unix:"))
    if remote != bool(args.tap):
        raise opt.UsageError("--tap goes with --sim unix:PATH (a running sim's control socket), and "
                             "it needs one")
    if args.port:
        from fap_py.serve import is_daemon_url

        if is_daemon_url(args.port):   # a bus `fap serve` owns: its tap, plus its clients
            return web.DaemonSource(args.port, args.protocol or "auto")
        return web.PortSource(args.port, args.baud or 0, args.protocol or "auto", opt.rs485_from_args(args))
    if args.mqtt:
        return web.MqttSource(args.mqtt, bus=args.bus)
    if args.capture:
        return web.CaptureSource(args.capture, args.protocol or "auto", args.baud or 0)
    if remote:
        return web.SimControlSource(args.sim, args.tap, bus=args.bus, protocol=args.protocol)
    return web.SimSource(args.sim, bus=args.bus, protocol=args.protocol)


def run(args: argparse.Namespace) -> int:
    from fap_py import web
    from fap_py.errors import PortError
    from fap_py.vbus import CaptureFormatError

    try:
        web.aiohttp_module()
    except web.MissingDependencyError as exc:
        raise opt.UsageError(str(exc)) from None
    token = args.token or os.environ.get("FAP_WEB_TOKEN") or None
    host, port = args.http
    try:
        source = _source(args)
        server = web.WebServer(source, host, port, token=token, ring=args.ring)
        stop = threading.Event()

        def on_signal(signum: int, frame: Any) -> None:
            stop.set()

        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            with server.start():
                url = f"{server.url}{'#token=' + token if token else ''}"
                info = source.describe()
                opt.emit(args, {"event": "ready", "url": server.url, "source": info},
                         f"fap web: {info['kind']} on {url}"
                         + (f"\nfap web: master port {info['master_port']}" if info.get("master_port") else "")
                         + "\nready")
                sys.stdout.flush()
                while not stop.wait(0.5):
                    pass
                snap = server.hub.snapshot()
            t = snap["totals"]
            opt.emit(args, {"event": "stopped", "frames": t["frames"], "bad": t["bad"],
                            "collisions": t["collisions"], "dropped": t["dropped_total"],
                            "source_error": snap["source"]["error"]},
                     f"fap web: stopped: {t['frames']} frames ({t['bad']} bad), "
                     f"{t['dropped_total']} dropped for slow browsers")
        finally:
            for s, h in old.items():
                signal.signal(s, h)
    except CaptureFormatError as exc:          # an unreadable file: exit 3, as fap monitor
        raise PortError(22, str(exc)) from exc
    return 0


__all__ = ["http_address", "register", "run"]
