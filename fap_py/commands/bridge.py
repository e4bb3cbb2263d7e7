"""``fap bridge``: publish RS-485 buses to an MQTT broker (docs/bridge.md).

    fap bridge --config bridge.toml
    fap bridge --config bridge.toml --check      # validate the file and exit
"""
from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bridge", help="connect buses to an MQTT broker (needs the 'bridge' extra)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Run the buses of a bridge.toml and publish them to an MQTT broker: "
        "<prefix>/<bus>/<node>/rx, .../tx (subscribed), .../state (retained), .../error, "
        "<prefix>/<bus>/stats, <prefix>/bridge/<host>/status. See docs/bridge.md.",
        epilog="example: fap bridge --config /etc/fap/bridge.toml -v")
    p.add_argument("--config", required=True, metavar="PATH", help="the bridge.toml")
    p.add_argument("--check", action="store_true", help="check the configuration and exit")
    p.add_argument("--connect-timeout", type=float, default=None, metavar="S",
                   help="fail if the broker is not reached within S seconds (None: retry forever)")
    p.add_argument("--drain", type=float, default=5.0, metavar="S",
                   help="at exit, wait up to S seconds for queued publications to reach the broker")
    p.add_argument("--debug", action="store_true", help="traceback on error")
    p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="log more (-v info, -vv debug), as before the subcommand")
    p.set_defaults(func=run)


def _fail(code: int, message: str) -> int:
    print(f"fap: error: {message}", file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except Exception:
        if args.debug:
            raise
        exc = sys.exc_info()[1]
        return _fail(1, f"{type(exc).__name__}: {exc}")


def _run(args: argparse.Namespace) -> int:
    from fap_py.bridge import (Bridge, BridgeConfigError, BrokerRefusedError, MissingDependencyError,
                               load_config)
    from fap_py.errors import PortError

    try:
        config = load_config(args.config)
    except OSError as exc:
        return _fail(3, f"{args.config}: {exc.strerror or exc}")
    except BridgeConfigError as exc:
        return _fail(2, f"{args.config}: {exc}")
    if args.check:
        print(f"{args.config}: ok: {len(config.buses)} bus(es), broker "
              f"{'mqtts' if config.broker.tls else 'mqtt'}://{config.broker.host}:{config.broker.port}, "
              f"prefix {config.prefix}, host {config.host}")
        return 0
    try:
        bridge = Bridge(config)
    except MissingDependencyError as exc:
        return _fail(2, str(exc))
    except PortError as exc:
        return _fail(3, str(exc))
    stop = threading.Event()
    interrupted = []

    def on_signal(signum: int, frame: object) -> None:
        interrupted.append(signum)
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            bridge.start()
        except PortError as exc:
            return _fail(3, str(exc))
        try:
            if args.connect_timeout is not None and not bridge.wait_connected(args.connect_timeout):
                return _fail(1, f"broker {config.broker.host}:{config.broker.port} not reached "
                             f"within {args.connect_timeout} s")
            while not stop.wait(0.5):
                if bridge.link.refused:
                    raise BrokerRefusedError(bridge.link.refused)
        except BrokerRefusedError as exc:
            return _fail(1, str(exc))
        finally:
            bridge.stop(drain=args.drain)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    return 130 if signal.SIGINT in interrupted else 0
