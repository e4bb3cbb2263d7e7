"""``fap bridge``: publish RS-485 buses to an MQTT broker (docs/bridge.md).

    fap bridge --config bridge.toml
    fap bridge --config bridge.toml --check      # validate the file and exit

The ports are named in the file (each bus its own line options), so the
command takes no --port; errors and exit codes are those of every command.
"""
from __future__ import annotations

import argparse
import logging
import signal
import threading
import time
from typing import TYPE_CHECKING

from ._options import (
    EXIT_INTERRUPTED,
    BusError,
    UsageError,
    add_command,
    add_output_options,
    emit,
    seconds,
)

if TYPE_CHECKING:   # pragma: no cover
    from fap_py.bridge import Bridge
    from fap_py.bridge.sdnotify import Notifier

log = logging.getLogger(__name__)


EXAMPLE = """\
fap bridge --config /etc/fap/bridge.toml --check
fap bridge --config /etc/fap/bridge.toml -v"""


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(
        sub, "bridge", help="connect buses to an MQTT broker (needs the 'bridge' extra)",
        description="Run the buses of a bridge.toml and publish them to an MQTT broker:\n"
        "  <prefix>/<bus>/<node>/rx, .../tx (subscribed), .../state (retained), .../error,\n"
        "  <prefix>/<bus>/stats, <prefix>/bridge/<host>/status.\n"
        "The ports and their line options are in the file. See docs/bridge.md.",
        example=EXAMPLE)
    p.add_argument("--config", required=True, metavar="PATH", help="the bridge.toml")
    p.add_argument("--check", action="store_true", help="check the configuration and exit")
    p.add_argument("--connect-timeout", type=seconds, default=None, metavar="S",
                   help="fail if the broker is not reached within S seconds (not given: retry "
                   "forever)")
    p.add_argument("--drain", type=seconds, default=5.0, metavar="S",
                   help="at exit, wait up to S seconds for queued publications to reach the broker")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The command; errors reach :func:`run_command` (one line, exit code by kind)."""
    from fap_py.bridge import (
        Bridge,
        BridgeConfigError,
        MissingDependencyError,
        load_config,
    )
    from fap_py.bridge.config import verify_files
    from fap_py.bridge.sdnotify import Notifier

    try:
        config = load_config(args.config)
    except BridgeConfigError as exc:            # a bad file is a usage error (exit 2)
        text = str(exc)                          # named once: the reader's own errors name it already
        raise UsageError(text if text.startswith(f"{args.config}: ") else f"{args.config}: {text}") from exc
    broker = ", ".join(b.url for b in config.brokers)
    if args.check:   # every file the configuration names: BridgeFileError (exit 3) names the key
        verify_files(config, ports=True)
        emit(args, {"event": "checked", "config": args.config, "ok": True, "buses": [b.name for b in config.buses],
                    "broker": config.broker.url, "brokers": [b.url for b in config.brokers],
                    "prefix": config.prefix, "host": config.host},
             f"{args.config}: ok: {len(config.buses)} bus(es), broker {broker}, "
             f"prefix {config.prefix}, host {config.host}")
        return 0
    try:
        bridge = Bridge(config)
    except MissingDependencyError as exc:       # the extra is not installed (exit 2)
        raise UsageError(str(exc)) from exc
    stop = threading.Event()
    interrupted = []

    def on_signal(signum: int, frame: object) -> None:
        interrupted.append(signum)
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    notifier = Notifier()      # systemd Type=notify; does nothing outside systemd
    try:
        try:
            bridge.start()
        except MissingDependencyError as exc:   # [metrics] without prometheus_client (exit 2)
            raise UsageError(str(exc)) from exc
        try:
            notifier.notify(READY=1, STATUS=bridge.status_line())
            _supervise(bridge, args, stop, notifier)
        finally:
            notifier.notify(STOPPING=1, STATUS="stopping: draining the outbox")
            bridge.stop(drain=args.drain)
    finally:
        notifier.close()
        for s, h in old.items():
            signal.signal(s, h)
    code = EXIT_INTERRUPTED if signal.SIGINT in interrupted else 0
    emit(args, {"event": "stopped", "signal": interrupted[0] if interrupted else None,
                "exit": code}, None)
    return code


def _supervise(bridge: "Bridge", args: argparse.Namespace, stop: threading.Event, notifier: "Notifier") -> None:
    """Until a signal: the broker's refusal and --connect-timeout end the run; the systemd
    watchdog is fed while the bridge's threads run, STATUS= follows the bridge's state."""
    from fap_py.bridge import BrokerRefusedError

    cfg = bridge.config.broker
    deadline = None if args.connect_timeout is None else time.monotonic() + args.connect_timeout
    tick = min(0.5, notifier.watchdog or 0.5)
    status = ""
    while not stop.wait(tick):
        if bridge.link.refused:
            raise BrokerRefusedError(bridge.link.refused)
        if deadline is not None:
            if bridge.wait_connected(0):
                deadline = None
            elif time.monotonic() > deadline:
                why = bridge.link.last_error
                where = f"broker {cfg.address}" if len(bridge.config.brokers) == 1 else \
                    f"no broker of {', '.join(b.address for b in bridge.config.brokers)}"
                raise BusError(f"{where} not reached within {args.connect_timeout} s"
                               + (f": {why}" if why else ""))
        if notifier.watchdog is not None and bridge.alive():
            notifier.notify(WATCHDOG=1)
        if notifier.enabled and bridge.status_line() != status:
            status = bridge.status_line()
            notifier.notify(STATUS=status)
