"""``fap serve``: one daemon owns a bus, every program shares it (docs/daemon.md).

    fap serve --protocol exec --port /dev/ttyUSB0 --listen unix:/run/fap/bus0.sock
    fap serve --config /etc/fap/bus0.toml --check
    fap serve status fapd:///run/fap/bus0.sock --json
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Any, Dict

from .. import _protocols
from ..rs485 import DEFAULT_BAUD
from . import _options as opt

#: protocols the daemon may run: the table's, and raw bytes with a reply rule
RAW = "raw"


def _choices() -> list:
    return [p.name for p in _protocols.all_protocols()] + [RAW]


def register(sub: argparse._SubParsersAction) -> None:
    p = opt.add_command(sub, "serve", help="daemon that owns a bus and shares it among programs "
                        "(fapd:// URLs)",
                        example="fap serve --protocol exec --port /dev/ttyUSB0 --listen "
                        "unix:/run/fap/bus0.sock\nfap serve status fapd:///run/fap/bus0.sock --json")
    p.add_argument("action", nargs="?", choices=["status"],
                   help="'status URL': a running daemon's clients, queues, wire-time shares")
    p.add_argument("url", nargs="?", help="status: the daemon's fapd:// URL")
    p.add_argument("--config", metavar="FILE", help="TOML file whose keys are these options' "
                   "names (protocol, port, listen = [...], baud, timeout ...); options override it")
    p.add_argument("--check", action="store_true",
                   help="check the configuration, take and release the port, and exit")
    p.add_argument("--protocol", choices=_choices(), help="the bus's protocol")
    opt.add_echo_option(opt.add_port_options(p, port_required=False, baud_default=None,
                                             baud_help="line speed, bit/s (default: the protocol's)"))
    opt.add_link_options(p, timeout_default=0.1, retries_default=3)
    g = p.add_argument_group("daemon")
    g.add_argument("--listen", metavar="ADDR", action="append",
                   help="unix:PATH or tcp://HOST:PORT (repeat for several)")
    g.add_argument("--token-file", metavar="FILE",
                   help="clients must send this file's token (?token= or FAP_SERVE_TOKEN); "
                   "needed for TCP beyond loopback")
    g.add_argument("--socket-mode", metavar="OCTAL", default="660", help="Unix socket mode")
    g.add_argument("--socket-owner", metavar="USER", help="Unix socket owner")
    g.add_argument("--socket-group", metavar="GROUP", help="Unix socket group")
    g.add_argument("--lock-dir", metavar="DIR", default="/var/lock",
                   help="directory of the UUCP lock file LCK..<tty> ('' = none)")
    g.add_argument("--queue", metavar="N", type=opt.positive, default=16,
                   help="requests one client may have waiting")
    g.add_argument("--max-weight", metavar="N", type=opt.positive, default=16,
                   help="the largest weight a client may ask for")
    g.add_argument("--max-priority", metavar="N", type=opt.count, default=3,
                   help="the highest priority a client may ask for")
    g.add_argument("--max-clients", metavar="N", type=opt.positive, default=64,
                   help="connections at once (more are refused)")
    g.add_argument("--client-timeout", metavar="S", type=opt.seconds, default=5.0,
                   help="a client must say hello, and finish each message it starts, within this")
    g.add_argument("--write-limit", metavar="BYTES", type=opt.positive, default=1 << 20,
                   help="answers a client leaves unread before it is cut off, bytes")
    g.add_argument("--metrics", metavar="ADDR",
                   help="Prometheus endpoint: tcp://HOST:PORT serves GET /metrics")
    g.add_argument("--slaves", metavar="IDS", help="fap: the slave ids the daemon polls")
    opt.add_output_options(p)
    p.set_defaults(func=run)


def _config(args: argparse.Namespace) -> Dict[str, Any]:
    """The file's keys under the command line's options."""
    out: Dict[str, Any] = {}
    if args.config:
        import tomllib

        try:
            with open(args.config, "rb") as f:
                out = tomllib.load(f)
        except OSError as exc:
            raise opt.FileError(exc.errno or 0, exc.strerror, args.config) from None
        except tomllib.TOMLDecodeError as exc:
            raise opt.UsageError(f"{args.config}: {exc}") from None
        out = {k.replace("-", "_"): v for k, v in out.items()}
        known = set(vars(args)) - {"func", "action", "url", "config", "check", "verbose", "debug"}
        bad = sorted(set(out) - known)
        if bad:
            raise opt.UsageError(f"{args.config}: unknown key(s) {', '.join(bad)}")
    parser_defaults = {"timeout": 0.1, "retries": 3, "socket_mode": "660", "lock_dir": "/var/lock",
                       "queue": 16, "max_weight": 16, "max_priority": 3, "max_clients": 64,
                       "rs485": "auto", "client_timeout": 5.0, "write_limit": 1 << 20, "rts_before": 0.0, "rts_after": 0.0, "rts_polarity": "high",
                       "gpio_line": 0}
    for k, v in vars(args).items():
        if v is None or v is False:
            continue
        if k in out and parser_defaults.get(k, object()) == v:
            continue                     # the file's value beats an option left at its default
        out[k] = v
    for k, v in parser_defaults.items():
        out.setdefault(k, v)
    return out


def _serve_config(args: argparse.Namespace):
    from ..serve import ServeConfig

    c = _config(args)
    for key in ("protocol", "port", "listen"):
        if not c.get(key):
            raise opt.UsageError(f"fap serve needs --{key} (or '{key}' in --config)")
    if c["protocol"] not in _choices():
        raise opt.UsageError(f"--protocol {c['protocol']!r}: one of {', '.join(_choices())}")
    slaves = c.get("slaves")
    if isinstance(slaves, str):
        try:
            slaves = [int(x) for x in slaves.replace(",", " ").split()]
        except ValueError:
            raise opt.UsageError(f"--slaves {slaves!r}: slave IDs, e.g. 1,2,3") from None
    ns = argparse.Namespace(**{**vars(args), **c})
    listen = c["listen"] if isinstance(c["listen"], list) else [c["listen"]]
    try:
        mode = int(str(c["socket_mode"]), 8)
    except ValueError:
        raise opt.UsageError(f"--socket-mode {c['socket_mode']!r}: octal, e.g. 660") from None
    baud = c.get("baud")
    if baud is None:
        baud = _protocols.get(c["protocol"]).default_baud if c["protocol"] != RAW else DEFAULT_BAUD
    return ServeConfig(protocol=c["protocol"], port=str(c["port"]), listen=[str(x) for x in listen],
                       baud=int(baud), rs485=opt.rs485_from_args(ns), timeout=float(c["timeout"]),
                       retries=int(c["retries"]), token_file=c.get("token_file"),
                       socket_mode=mode, socket_owner=c.get("socket_owner"),
                       socket_group=c.get("socket_group"), lock_dir=c["lock_dir"] or None,
                       queue=int(c["queue"]), max_weight=int(c["max_weight"]),
                       max_priority=int(c["max_priority"]), max_clients=int(c["max_clients"]),
                       hello_timeout=float(c["client_timeout"]), body_timeout=float(c["client_timeout"]),
                       write_limit=int(c["write_limit"]), slaves=list(slaves or []),
                       metrics=c.get("metrics"))


def run(args: argparse.Namespace) -> int:
    if args.action == "status":
        return _status(args)
    if args.url:
        raise opt.UsageError(f"unexpected argument {args.url!r} (status URL shows a daemon)")
    cfg = _serve_config(args)
    if args.check:
        return _check(args, cfg)
    return _serve(args, cfg)


def _check(args: argparse.Namespace, cfg: Any) -> int:
    from ..serve import Daemon
    from ..serve._url import parse_listen

    for text in cfg.listen:
        parse_listen(text)
    d = Daemon(cfg)                 # checks the configuration (and reads the token file)
    d.open_port()                   # takes the lock file and the port, as the daemon will
    d.close_now()
    opt.emit(args, {"event": "checked", "ok": True, "protocol": cfg.protocol, "port": cfg.port,
                    "listen": cfg.listen},
             f"ok: {cfg.protocol} on {cfg.port} at {cfg.baud} baud, listen {' '.join(cfg.listen)}")
    return 0


def _serve(args: argparse.Namespace, cfg: Any) -> int:
    import asyncio
    import signal

    from ..bridge.sdnotify import Notifier
    from ..serve import Daemon

    notifier = Notifier()
    summary: Dict[str, Any] = {}

    async def main() -> None:
        d = Daemon(cfg)
        await d.start()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, d.stop)
        opt.emit(args, {"event": "ready", "pid": os.getpid(), "protocol": cfg.protocol,
                        "port": cfg.port, "baud": cfg.baud, "listen": d.listening,
                        "metrics": d.metrics_url},
                 f"ready: {cfg.protocol} on {cfg.port} at {cfg.baud} baud, clients at "
                 f"{' '.join(d.listening)}")
        sys.stdout.flush()
        notifier.notify(READY=1, STATUS=f"serving {cfg.port} at {' '.join(d.listening)}")
        dog = None
        every = notifier.watchdog
        if every:
            async def feed() -> None:
                while True:
                    notifier.notify(WATCHDOG=1)
                    await asyncio.sleep(every)
            dog = loop.create_task(feed())
        try:
            await d._stopped.wait()
        finally:
            notifier.notify(STOPPING=1)
            if dog:
                dog.cancel()
            summary.update(d.status()["totals"])
            await d.aclose()

    try:
        asyncio.run(main())
    finally:
        notifier.close()
    opt.emit(args, {"event": "stats", **summary},
             f"{summary.get('transactions', 0)} transactions, {summary.get('errors', 0)} failed, "
             f"{summary.get('late', 0)} late, {summary.get('cut_off', 0)} clients cut off")
    return 0


def _status(args: argparse.Namespace) -> int:
    from ..serve import status

    if not args.url:
        raise opt.UsageError("fap serve status needs the daemon's URL (fapd:///path or fapd://host:port)")
    st = status(args.url)
    if args.json:
        opt.emit(args, {"event": "status", **st}, None)
        return 0
    d, t = st["daemon"], st["totals"]
    print(f"daemon pid {d['pid']}: {d['protocol']} on {d['port']} at {d['baud']} baud, "
          f"port {d['port_state']}, up {d['uptime_s']} s")
    print(f"  {t['transactions']} transactions, {t['errors']} failed, {t['late']} late, "
          f"{t['queue_full']} refused (queue full), {t['cut_off']} cut off, {t['clients']} clients")
    for c in st["clients"]:
        print(f"  client {c['client']} {c['name'] or '-'} ({c['peer']}): weight {c['weight']} "
              f"priority {c['priority']}, queued {c['queued']}, {c['transactions']} transactions, "
              f"share {c['share'] * 100:.1f}%, late {c['late']}, errors {c['errors']}")
    return 0
