"""``fap soak``: fault soak of every protocol in the table (fap_py.soak).

FAP and exec async run a master in this process and N slave *processes* on
the paced virtual bus with bit errors and byte drops; one slave is killed
(SIGKILL) and restarted, and the master's port is disconnected and comes
back. Every message carries its own sequence number and a SHA-256 digest,
so the report can say: sent / delivered intact / corrupted / duplicated /
lost, which counters account for the losses, how long recovery took, and
how RSS, threads and fds of every process moved.

mikroC and G485 guard their frames with an 8-bit check: they run on the
same bus with the same faults (at a higher bit error rate) and count how
many corrupted messages those checks let through, a rate to document, not
hide; a simulated bit-error channel fed to the decoders gives a second
figure.

This module parses the options and maps the reports' verdicts to the exit
status; the engine is :mod:`fap_py.soak` (the harness and one plug-in per
protocol). The exit status is 1 when a report's ``ok`` is false (FAP or
exec async delivered anything corrupted or twice, or returned a stale reply;
mikroC delivered a frame twice); docs/reliability.md has figures.
"""
from __future__ import annotations

import argparse
import dataclasses
from typing import Any, Dict, List

from ._node import CLIENT, handles_signals, long_running

ALL = "all"


class _Choices(List[str]):
    """``--protocol``'s choices: every protocol's one name and ``all`` (what help and
    completion list); an alias of a name is accepted too."""

    def __contains__(self, text: object) -> bool:
        from fap_py import _protocols

        if list.__contains__(self, text):
            return True
        try:
            return isinstance(text, str) and _protocols.get(text).name in self
        except _protocols.UnknownProtocolError:
            return False


def _choices() -> List[str]:
    from fap_py import _protocols

    return _Choices([*_protocols.names(), ALL])


def _selected(a: argparse.Namespace) -> List[str]:
    """The protocols ``--protocol`` names, by their one name, in table order."""
    from fap_py import _protocols

    return _choices()[:-1] if a.protocol == ALL else [_protocols.get(a.protocol).name]


def register(sub: argparse._SubParsersAction) -> None:
    from fap_py.soak.harness import Config, max_slaves

    from ._options import add_command, add_link_options, add_output_options, baud, count, seconds

    d = Config()
    names = _choices()[:-1]
    p = add_command(
        sub, "soak", help="fault soak: master + slave processes on the paced virtual bus",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
        example="fap soak --seconds 30 --slaves 4 --json")
    p.add_argument("--protocol", choices=_choices(), default=ALL, help="what to soak")
    # the options set a Config field of the same name (--bit-error-rate: bit_error_rate)
    types = {"S": seconds, "P": seconds, "R": seconds, "N": count}
    most = min(max_slaves(n) for n in names)
    options = [
        ("seconds", "S", "duration of each protocol's bus soak"),
        ("slaves", "N", f"slave processes (1..{most})"),
        ("baud", "N", "paced bus rate, bit/s"),
        ("bit_error_rate", "P", "per byte, every port"),
        ("drop_rate", "P", "per byte, every port"),
        ("bus8_bit_error_rate", "P", "mikroC / G485 bus soak: bit error rate per byte (higher than "
         "--bit-error-rate, so that enough frames are damaged to measure what the 8-bit checks let "
         "through)"),
        ("link", "", ""),
        ("master_rate", "R", "FAP messages/s the master queues"),
        ("slave_rate", "R", "FAP messages/s each slave queues"),
        ("check8_seconds", "S", "mikroC / G485 channel run time"),
        ("check8_ber", "P", "mikroC / G485 channel bit error rate"),
        ("sample", "S", "resource sampling period, seconds"),
        ("seed", "N", "seed of every random choice and fault"),
    ]
    for name, metavar, text in options:
        if name == "link":       # --timeout, --retries: the request/reply masters'
            link = add_link_options(p, timeout_default=d.timeout, retries_default=d.retries)
            link.description = "exec async, mikroC and G485 master"
            continue
        p.add_argument("--" + name.replace("_", "-"), metavar=metavar, default=getattr(d, name),
                       type=baud if name == "baud" else types[metavar], help=text)
    add_output_options(p)
    long_running(p, CLIENT, handles_signals(run))   # its own SIGINT/SIGTERM stop


def _value(v: Any) -> str:
    """One value of the report as text: no Python reprs (True, None, quotes)."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_value(x) for x in v) or "-"
    return str(v)


def _lines(obj: Dict[str, Any], indent: str) -> List[str]:
    """``key: value`` lines (the JSON's keys); a mapping of plain values on one line
    (``key: a 1, b 2``), a deeper one as its own indented block."""
    out: List[str] = []
    for k, v in obj.items():
        if isinstance(v, dict) and any(isinstance(x, dict) for x in v.values()):
            out.append(f"{indent}{k}:")
            out += _lines(v, indent + "  ")
        elif isinstance(v, dict):
            out.append(f"{indent}{k}: " + (", ".join(f"{a} {_value(b)}" for a, b in v.items())
                                           or "-"))
        else:
            out.append(f"{indent}{k}: {_value(v)}")
    return out


def _human(res: Dict[str, Any]) -> str:
    body = {k: v for k, v in res.items() if k not in ("protocol", "master_stats", "event")}
    return "\n".join([f"== {res['protocol']}"] + _lines(body, "  "))


def config(a: argparse.Namespace) -> Any:
    """The :class:`fap_py.soak.Config` of the parsed options (checked: a bad one is a
    usage error naming it)."""
    from fap_py.soak.harness import Config, max_slaves

    from ._options import UsageError

    most = min(max_slaves(n) for n in _selected(a))
    if not 1 <= a.slaves <= most or a.seconds <= 0 or a.sample <= 0:
        raise UsageError(f"need --slaves 1..{most}, --seconds > 0, --sample > 0 (not {a.slaves}, "
                         f"{a.seconds}, {a.sample})")
    if not (a.bit_error_rate <= 1 and a.drop_rate <= 1 and a.check8_ber <= 1 and a.bus8_bit_error_rate <= 1):
        raise UsageError("--bit-error-rate, --drop-rate, --bus8-bit-error-rate and --check8-ber "
                         "are probabilities (0..1)")
    return Config(**{f.name: getattr(a, f.name) for f in dataclasses.fields(Config) if f.name != "stop"})


def run(a: argparse.Namespace) -> int:
    """The command: one result per protocol (JSON line or text); exit 1 if a report's
    verdict ``ok`` is false (FAP or exec async delivered anything corrupted or twice,
    or mikroC delivered a frame twice; mikroC / G485 corruption is measured, not failed
    on). Errors reach ``run_command``."""
    from fap_py import soak

    from ._node import stop_on_sigterm, timed_progress
    from ._options import EXIT_INTERRUPTED, emit

    cfg = config(a)
    failed = False
    with stop_on_sigterm() as stop:
        cfg.stop = stop         # the soak loops end early when it is set
        for proto in _selected(a):
            with timed_progress(f"soak {proto}", soak.duration(proto, cfg)):
                res = soak.run(proto, cfg)
            if stop.is_set():
                res["interrupted"] = True
            emit(a, {"event": "result", **res}, _human(res))
            failed |= not res.get("ok", True)
            if stop.is_set():
                break
    if stop.is_set():     # Ctrl-C / SIGTERM: the results so far, then exit 130
        return EXIT_INTERRUPTED
    return 1 if failed else 0
