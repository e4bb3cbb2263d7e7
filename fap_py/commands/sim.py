"""``fap sim``: simulated devices of every protocol from one config file (fap_py.sim).

The forms (docs/sim.md)::

    fap sim CONFIG [--port PATH] [--control unix:PATH] [--json]   run until Ctrl-C / SIGTERM
    fap sim --check CONFIG                                          validate (exit 2 on an error)
    fap sim --schema                                                the config's JSON Schema
    fap sim fault add KIND --control unix:PATH [--node N|all] [--bus NAME] [--probability P] [--ms MS]
    fap sim fault list --control unix:PATH [--json]
    fap sim fault remove ID|all --control unix:PATH [--json]
    fap sim status --control unix:PATH [--json]
"""
from __future__ import annotations

import argparse
import json
from typing import Any, Dict, List

from ._node import stop_on_sigterm
from ._options import (
    EXIT_OK,
    EXIT_USAGE,
    Parser,
    UsageError,
    add_command,
    add_echo_option,
    add_output_options,
    add_port_options,
    emit,
    integer,
    plural,
    rs485_from_args,
    seconds,
)

_ACTIONS = ("fault", "status")


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(
        sub, "sim", help="simulated devices of every protocol from one config file",
        description="Run the buses and nodes a TOML/JSON/YAML config declares (exec async, "
        "mikroC, G485 and FAP nodes; value generators; faults switched at run time through "
        "--control). Also: --check CONFIG, --schema, and the control CLI: "
        "'fap sim fault add|list|remove --control unix:PATH ...', "
        "'fap sim status --control unix:PATH' (docs/sim.md).",
        example="fap sim examples/sim/site.toml --control unix:/tmp/sim.sock\n"
        "fap sim --check site.toml\n"
        "fap sim fault add no_reply --node 5 --control unix:/tmp/sim.sock\n"
        "fap sim status --control unix:/tmp/sim.sock --json")
    p.add_argument("config", metavar="CONFIG", nargs="?",
                   help="the config file (or the action 'fault' / 'status')")
    p.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    _run_options(p)
    p.set_defaults(func=run)


def _run_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--check", action="store_true", help="validate CONFIG and exit (0: good, 2: the error)")
    p.add_argument("--schema", action="store_true", help="print the config's JSON Schema and exit")
    p.add_argument("--control", metavar="unix:PATH", help="control socket (JSON lines)")
    p.add_argument("--replay", metavar="CAPTURE", help="answer each recorded request of a virtual "
                   "bus capture with its recorded reply and delay (needs --protocol)")
    p.add_argument("--learn", metavar="CAPTURE", help="write a config that reproduces the devices "
                   "of a virtual bus capture (needs --protocol; stdout without -o)")
    p.add_argument("-o", "--output", metavar="FILE", help="--learn: write the config here")
    from fap_py.sim._replay import replay_protocols
    p.add_argument("--protocol", choices=replay_protocols(),
                   help="--replay/--learn: the capture's protocol")
    p.add_argument("--master-port", metavar="N", type=int, default=None,
                   help="--replay: the capture port of the master (default: the first sender)")
    g = add_port_options(p, baud_default=None, port_required=False,
                         port_help="the port of the config's one bus, instead of the config's",
                         baud_help="line speed (default: the bus's baud, or the protocol's default)")
    add_echo_option(g)
    add_output_options(p)


def _action_parser() -> Parser:
    ap = Parser(prog="fap sim", add_help=True)
    acts = ap.add_subparsers(dest="action", metavar="ACTION", required=True, parser_class=Parser)
    fault = acts.add_parser("fault", help="faults of a running sim")
    fa = fault.add_subparsers(dest="fault_action", metavar="fault ACTION", required=True,
                              parser_class=Parser)
    add = fa.add_parser("add", help="add a fault")
    from fap_py.sim._faults import KINDS
    add.add_argument("kind", choices=list(KINDS), help="the fault kind")
    add.add_argument("--node", default="all", help="a node address, or all")
    add.add_argument("--bus", default=None, help="the bus's name (default: every bus)")
    add.add_argument("--probability", type=seconds, default=1.0, help="0..1")
    add.add_argument("--ms", type=seconds, default=None,
                     help="late_reply: the delay; split: the gap between the pieces (milliseconds)")
    add.add_argument("--rate", type=seconds, default=None, help="bit_errors, byte_drops: per byte, 0..1")
    add.add_argument("--word", type=integer, default=None,
                     help="error_reply: the error word's bits (1..0xffff)")
    add.add_argument("--seed", type=int, default=None, help="seed of the probability draws")
    add.add_argument("--at", type=seconds, default=None, help="in force from this many seconds from now")
    add.add_argument("--for", dest="duration", type=seconds, default=None,
                     help="in force this many seconds (then removed; with --every: of each period)")
    add.add_argument("--every", type=seconds, default=None, help="repeat: a period in seconds (needs --for)")
    add.add_argument("--direction", choices=["reply", "request"], default=None,
                     help="bit_errors, byte_drops: damage replies (default) or the requests the node hears")
    lst = fa.add_parser("list", help="the active faults")
    rm = fa.add_parser("remove", help="remove a fault")
    rm.add_argument("id", help="the fault's id, or all")
    st = acts.add_parser("status", help="nodes, requests served, faults applied")
    for q in (add, lst, rm, st):
        q.add_argument("--control", metavar="unix:PATH", required=True, help="the sim's control socket")
        add_output_options(q)
    return ap


def run(args: argparse.Namespace) -> int:
    if args.config in _ACTIONS:
        return _action(args)
    if args.rest:   # options after CONFIG: REMAINDER took them
        extra = Parser(prog="fap sim", add_help=False)
        _run_options(extra)
        try:
            extra.parse_args(args.rest, namespace=args)
        except SystemExit as exc:     # a usage error, already said in the one error style
            return int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
    if args.schema:
        from fap_py.sim._schema import schema
        print(json.dumps(schema(), indent=2))
        return EXIT_OK
    if args.learn:
        if args.protocol is None:
            raise UsageError("--learn needs --protocol")
        from fap_py.sim._learn import learn
        from fap_py.sim._replay import load_capture

        text = learn(load_capture(args.learn, args.protocol, args.baud), args.protocol, args.master_port,
                     args.learn)
        if args.output:
            from fap_py.errors import FileError
            try:
                with open(args.output, "w", encoding="utf-8") as f:
                    f.write(text)
            except OSError as exc:
                raise FileError(exc.errno or 5, f"-o: {exc.strerror}", args.output) from None
            emit(args, {"event": "learned", "output": args.output}, f"wrote {args.output}")
        else:
            print(text, end="", flush=True)
        return EXIT_OK
    if args.replay:
        if args.config is not None:
            raise UsageError("--replay CAPTURE replaces CONFIG: give one of them")
        if args.protocol is None:
            raise UsageError("--replay needs --protocol")
        return _replay(args)
    if args.config is None:
        raise UsageError("fap sim needs CONFIG (or --schema, --replay, or the action fault / status)")
    from fap_py.sim import load

    cfg = load(args.config)
    if args.check:
        n = sum(len(b["node"]) for b in cfg["bus"])
        emit(args, {"event": "check", "ok": True, "config": args.config, "buses": len(cfg["bus"])},
             f"{args.config}: ok ({plural(len(cfg['bus']), 'bus', 'buses')}, {plural(n, 'node entry', 'node entries')})")
        return EXIT_OK
    return _serve(args, cfg)


def _serve(args: argparse.Namespace, cfg: Dict[str, Any]) -> int:
    from fap_py.sim import Sim
    from fap_py.sim._control import ControlServer, unix_path

    if args.control:
        unix_path(args.control)    # a bad spec before anything opens
    rs485 = rs485_from_args(args) if args.port else None
    with stop_on_sigterm() as done, Sim(cfg, port=args.port, baud=args.baud, rs485=rs485) as sim:
        server = ControlServer(sim, args.control) if args.control else None
        try:
            buses: List[Dict[str, Any]] = [{"name": b.name, "protocol": b.protocol, "master_port": b.master_port,
                      "nodes": len(b.addresses)} for b in sim.buses]
            text = "\n".join(f"bus {b['name']} ({b['protocol']}): {plural(b['nodes'], 'node')}; "
                             f"master port: {b['master_port'] or args.port or 'the config port'}"
                             for b in buses)
            emit(args, {"event": "ready", "buses": buses, "control": args.control},
                 text + f"\nready{' (control ' + args.control + ')' if args.control else ''}")
            while not done.wait(0.5):
                pass
            st = sim.status()
        finally:
            if server is not None:
                server.close()
    emit(args, {"event": "stopped", **st}, f"stopped: {counters_text(st)}")
    return EXIT_OK


def status_lines(st: Dict[str, Any]) -> List[str]:
    """A sim status as text: each bus, each node's counters, the faults in force
    (``fap sim status``, and ``fap monitor --sim-control`` after its summary)."""
    text = []
    for b in st["buses"]:
        text.append(f"bus {b['name']} ({b['protocol']}): {plural(b['requests'], 'request')}, "
                    f"master port {b['master_port'] or '-'}")
        for n in b["nodes"]:
            faults = ", ".join(f"{k} {v}" for k, v in n["faults"].items())
            text.append(f"  node {n['address']}: {n['requests']} requests, {n['replies']} replies"
                        + (f", faults {faults}" if faults else "") + (f", state {n['state']}" if "state" in n else ""))
    text.append("faults: " + (", ".join(_fault_text(f) for f in st["faults"]) or "none"))
    return text


def counters_text(st: Dict[str, Any]) -> str:
    """A sim status's counters in one line (``fap sim``'s last line, ``fap monitor
    --sim-control``'s summary)."""
    return (f"{plural(st['requests'], 'request')} served, faults applied: "
            + (", ".join(f"{k} {v}" for k, v in st["faults_applied"].items() if v) or "none"))


def _replay(args: argparse.Namespace) -> int:
    from fap_py.sim._replay import Replay

    rs485 = rs485_from_args(args) if args.port else None
    with stop_on_sigterm() as done, \
            Replay(args.replay, args.protocol, port=args.port, baud=args.baud,
                   master_port=args.master_port, rs485=rs485) as rp:
        summary = rp.responder.summary()
        emit(args, {"event": "ready", "buses": [{"name": "replay", "protocol": args.protocol,
                                                  "master_port": rp.master_port}], **summary},
             f"replay of {args.replay} ({args.protocol}): {plural(summary['distinct_requests'], 'request')} "
             f"recorded; master port: {rp.master_port or args.port}\nready")
        while not done.wait(0.5):
            pass
        summary = rp.responder.summary()
    emit(args, {"event": "stopped", **summary},
         f"stopped: {summary['matched']} matched, {summary['unmatched']} not in the capture")
    return EXIT_OK


def _action(args: argparse.Namespace) -> int:
    from fap_py.sim._control import request

    a = _action_parser().parse_args([args.config, *args.rest])
    if a.action == "status":
        ans = request(a.control, {"cmd": "status"})
        _check(ans)
        emit(a, {"event": "status", **ans}, "\n".join(status_lines(ans)))
        return EXIT_OK
    if a.fault_action == "add":
        req: Dict[str, Any] = {"cmd": "fault.add", "kind": a.kind, "probability": a.probability}
        if a.node != "all":
            try:
                req["node"] = int(a.node, 0)
            except ValueError:
                raise UsageError(f"--node takes an address or all, not {a.node!r}") from None
        if a.bus is not None:
            req["bus"] = a.bus
        if a.ms is not None:
            req["ms"] = a.ms
        elif a.kind == "late_reply":
            raise UsageError("late_reply needs --ms MS")
        for key, value in (("seed", a.seed), ("rate", a.rate), ("word", a.word), ("at", a.at),
                           ("for", a.duration), ("every", a.every), ("direction", a.direction)):
            if value is not None:
                req[key] = value
        ans = request(a.control, req)
        _check(ans)
        emit(a, {"event": "fault_added", **ans}, f"added {_fault_text(ans['fault'])}")
        return EXIT_OK
    if a.fault_action == "list":
        ans = request(a.control, {"cmd": "fault.list"})
        _check(ans)
        emit(a, {"event": "faults", **ans}, "\n".join(_fault_text(f) for f in ans["faults"]) or "no faults")
        return EXIT_OK
    fid: Any = a.id
    if fid != "all":
        try:
            fid = int(fid, 10)
        except ValueError:
            raise UsageError(f"remove takes a fault id or all, not {a.id!r}") from None
    ans = request(a.control, {"cmd": "fault.remove", "id": fid})
    _check(ans)
    emit(a, {"event": "fault_removed", **ans}, "removed " + (", ".join(_fault_text(f) for f in ans["removed"]) or "nothing"))
    return EXIT_OK


def _check(ans: Dict[str, Any]) -> None:
    if not ans.get("ok"):
        raise UsageError(f"the sim refused: {ans.get('error')}")


def _fault_text(f: Dict[str, Any]) -> str:
    par = "".join(f" {k} {f[k]:g}" for k in ("ms", "rate") if k in f)
    par += f" word 0x{f['word']:04x}" if "word" in f else ""
    sched = "".join(f" {k} {f[k]:g} s" for k in ("at", "for", "every") if k in f)
    sched += (" (on)" if f["active"] else " (off)") if "active" in f else ""
    hung = f" hung {', '.join(f['hung_nodes'])}" if f.get("hung_nodes") else ""
    return (f"#{f['id']} {f['kind']}{par} bus {f['bus'] or '*'} node {f['node']} "
            f"p={f['probability']:g}{sched} applied {f['applied']}{hung}")
