"""``fap g485``: Gicren G485 devices: simulate them, talk to them as the master, scan.

    fap g485 sim --port /dev/pts/3 --address 1 --address 2 --eeprom-dir /tmp/g485
    fap g485 read --port /dev/ttyUSB0 --address 1 --register 1 --registers 7
    fap g485 write --port /dev/ttyUSB0 --address 1 --register 8 0x32 0x10
    fap g485 set --port /dev/ttyUSB0 --address 1 save_eeprom
    fap g485 error-word --port /dev/ttyUSB0 --address 1
    fap g485 handshake --port /dev/ttyUSB0 --address 1 --count 0 --interval 1
    fap g485 scan --port /dev/ttyUSB0

"""
from __future__ import annotations

import argparse
import os
import time
from typing import Any, Callable, Dict, List, Tuple, Union

from fap_py import _protocols

from .. import _options as opt
from .._node import CLIENT, SERVER, long_running, repetitions, scan, scan_summary, stop_on_sigterm

PROTOCOL = _protocols.get("g485")   # device IDs, broadcast ID, default baud: from the binding


def register(sub: argparse._SubParsersAction) -> None:
    p = opt.add_command(sub, "g485", help="Gicren G485: device simulator, master transactions, scan",
                        example="fap g485 read --port /dev/ttyUSB0 --address 1 --register 1 --registers 7")
    cmds = opt.add_actions(p, "g485_command")

    def master(q: argparse.ArgumentParser, *, repeat: bool = True, address: bool = True,
               check: bool = False) -> None:
        opt.add_echo_option(opt.add_port_options(q, baud_default=PROTOCOL.default_baud))
        opt.add_link_options(q, timeout_default=0.1, retries_default=2)
        opt.add_output_options(q)
        if address:
            q.add_argument("--address", type=opt.integer, required=True,
                           help=f"device ID {PROTOCOL.node_min}..{PROTOCOL.node_max} "
                           f"({PROTOCOL.broadcast} = broadcast)")
        if check:      # only writes and sets are confirmed
            q.add_argument("--check", choices=["handshake", "reread", "none"], default="handshake",
                           help="how the write or set is confirmed")
        if repeat:
            opt.add_repeat_options(q)

    s = opt.add_command(cmds, "sim", help="simulate devices on a port until interrupted",
                        example="fap g485 sim --port /dev/pts/3 --address 1 --address 2")
    opt.add_echo_option(opt.add_port_options(s, baud_default=PROTOCOL.default_baud))
    opt.add_output_options(s)
    s.add_argument("--address", type=opt.integer, action="append", required=True,
                   help="a device ID to simulate (repeat for several devices)")
    s.add_argument("--eeprom-dir", help="keep each device's EEPROM in DIR/g485-<ID>.json")
    s.add_argument("--wake-up-loss", action="store_true",
                   help="lose the first burst after power-on/reset (baud detection)")
    s.add_argument("--seed", type=opt.integer, default=0, help="seed of bulk-mode discards")
    long_running(s, SERVER, run_sim)

    r = opt.add_command(cmds, "read", help="read registers",
                        example="fap g485 read --port /dev/ttyUSB0 --address 1 --register 1 --registers 7")
    master(r)
    r.add_argument("--register", type=opt.integer, required=True, help="first register")
    r.add_argument("--registers", type=opt.positive, default=1, help="how many registers")
    long_running(r, CLIENT, run_read)

    w = opt.add_command(cmds, "write", help="write registers",
                        example="fap g485 write --port /dev/ttyUSB0 --address 1 --register 8 0x32 0x10")
    master(w, repeat=False, check=True)
    w.add_argument("--register", type=opt.integer, required=True, help="first register")
    w.add_argument("values", type=opt.integer, nargs="+", help="register values 0..255")
    w.set_defaults(func=run_write)

    t = opt.add_command(cmds, "set", help="send a Set command (factory_reset, save_eeprom, reset, ...)",
                        example="fap g485 set --port /dev/ttyUSB0 --address 1 save_eeprom")
    master(t, repeat=False, check=True)
    t.add_argument("command", help="SetCommand name or value")
    t.set_defaults(func=run_set)

    e = opt.add_command(cmds, "error-word", help="read the error word",
                        example="fap g485 error-word --port /dev/ttyUSB0 --address 1")
    master(e)
    long_running(e, CLIENT, run_error_word)

    h = opt.add_command(cmds, "handshake", help="read the device's check byte",
                        example="fap g485 handshake --port /dev/ttyUSB0 --address 1 --count 0")
    master(h)
    long_running(h, CLIENT, run_handshake)

    c = opt.add_command(cmds, "scan", help="find the devices that answer a handshake "
                        "(progress bar on a terminal, devices printed as they answer)",
                        example=f"fap g485 scan --port /dev/ttyUSB0 --first {PROTOCOL.node_min} "
                        f"--last {PROTOCOL.node_max}")
    master(c, repeat=False, address=False)
    c.set_defaults(timeout=0.05, retries=0)
    c.add_argument("--first", type=opt.integer, default=PROTOCOL.node_min, help="first ID to try")
    c.add_argument("--last", type=opt.integer, default=PROTOCOL.node_max, help="last ID to try")
    long_running(c, CLIENT, run_scan)


def _rs485(args: argparse.Namespace) -> Any:
    """Line options for a device path or libfap's tcp:// / rfc2217:// (the C port
    layer); None for a pyserial URL (it has its own)."""
    from fap_py.port import port_kind

    pyserial_url = port_kind(args.port) == "other"   # a scheme the C port layer does not open
    return None if pyserial_url else opt.rs485_from_args(args)


def sim_config(args: argparse.Namespace) -> Dict[str, Any]:
    """The ``fap sim`` site ``fap g485 sim`` runs (docs/sim.md): one G485 bus on ``--port``,
    a node per ``--address`` (its EEPROM in DIR/g485-<ID>.json with ``--eeprom-dir``); the
    sim's seed is ``--seed``, so device N draws its bulk-mode discards from seed + N."""
    nodes: List[Dict[str, Any]] = []
    for address in args.address:
        node: Dict[str, Any] = {"address": address}
        if args.eeprom_dir:
            node["eeprom"] = os.path.join(args.eeprom_dir, f"g485-{address}.json")
        if args.wake_up_loss:
            node["wake_up_loss"] = True
        nodes.append(node)
    return {"sim": {"seed": args.seed},
            "bus": [{"name": "g485", "protocol": "g485", "port": args.port, "baud": args.baud,
                     "node": nodes}]}


def run_sim(args: argparse.Namespace) -> int:
    from fap_py.g485.codec import MAX_SLAVE_ADDRESS, MIN_SLAVE_ADDRESS
    from fap_py.g485.errors import G485ValueError
    from fap_py.g485.transaction import whole_arg
    from fap_py.sim import Sim

    # the errors the device simulator gave, not the config's paths (the user wrote no config)
    for i, address in enumerate(args.address):
        whole_arg(address, "device address", MIN_SLAVE_ADDRESS, MAX_SLAVE_ADDRESS)
        if address in args.address[:i]:
            raise G485ValueError(f"a device with ID {address} is already on this port")
    if args.eeprom_dir:
        try:
            os.makedirs(args.eeprom_dir, exist_ok=True)
        except OSError as exc:   # a file there, say: "File exists" named nothing
            why = "not a directory" if isinstance(exc, FileExistsError) else exc.strerror
            raise OSError(exc.errno, f"--eeprom-dir: cannot use it as the EEPROM directory "
                          f"({why})", args.eeprom_dir) from None
    t0 = time.monotonic()
    with stop_on_sigterm() as done, Sim(sim_config(args), rs485=_rs485(args)) as sim:
        bus = sim.buses[0]
        name = getattr(bus.runner.port, "path", args.port)
        opt.emit(args, {"event": "ready", "port": name, "addresses": args.address},
                 f"ready: simulating G485 device{'s' if len(args.address) > 1 else ''} "
                 f"{', '.join(map(str, args.address))} on {name}")
        while not done.wait(0.2):
            if bus.runner.error is not None:
                raise bus.runner.error
        st = bus.status()
        events, reopened = bus.runner.transactions, st["reopened"]
        replies = sum(n["replies"] for n in st["nodes"])
    opt.emit(args, {"event": "summary", "seconds": round(time.monotonic() - t0, 3),
                "packets": events, "replies": replies, "reopened": reopened},
             f"summary: {opt.plural(events, 'packet')} handled, {opt.plural(replies, 'reply', 'replies')} "
             f"sent, port reopened {opt.plural(reopened, 'time')}, {time.monotonic() - t0:.1f} s")
    return 0


def _master(args: argparse.Namespace):
    from fap_py.g485 import G485Master

    rs485 = _rs485(args)
    return G485Master(args.port, args.baud, timeout=args.timeout or 0.001, retries=args.retries,
                      check=getattr(args, "check", "handshake"), rs485=rs485,
                      echo=bool(args.echo_suppression) and rs485 is None)


def _poll(args: argparse.Namespace, what: str, ask: Callable[[Any], Any],
          show: Callable[[Any], Tuple[Dict[str, Any], str]]) -> int:
    """``--count`` transactions ``ask(master)``, each printed by ``show``; a
    failed one is printed and polling goes on (as exec and mikroC do); Ctrl-C
    ends with the summary (exit 130); exit 1 if any failed."""
    from fap_py.g485 import G485Error
    from fap_py.g485.errors import G485ValueError

    done = failed = 0
    interrupted = False
    with _master(args) as m:
        try:
            for _ in repetitions(args):
                done += 1
                try:
                    obj, text = show(ask(m))
                except G485ValueError:
                    raise                       # a usage error (a broadcast read): exit 2
                except G485Error as exc:
                    if args.count == 1:
                        raise                   # one request: its error is the one line
                    failed += 1
                    opt.emit(args, {"event": "error", "address": args.address, "error": str(exc)},
                             f"device {args.address}: {exc}")
                    continue
                opt.emit(args, {"event": "reply", "address": args.address, **obj}, text)
        except KeyboardInterrupt:
            interrupted = True
    if interrupted or args.count != 1:
        opt.emit(args, {"event": "summary", "address": args.address, "requests": done,
                    "failed": failed, **({"interrupted": True} if interrupted else {})},
                 f"{opt.plural(done, what)} to device {args.address}, {failed} failed"
                 + (" (interrupted)" if interrupted else ""))
    if interrupted:
        return opt.EXIT_INTERRUPTED
    if failed:
        raise opt.BusError(f"{failed} of {opt.plural(done, what)} to device {args.address} failed")
    return 0


def run_read(args: argparse.Namespace) -> int:
    def show(data: Any) -> Tuple[Dict[str, Any], str]:
        return ({"register": args.register, "values": list(data)},
                "\n".join(f"register {args.register + i}: {v} (0x{v:02x})"
                          for i, v in enumerate(data)))

    return _poll(args, "read", lambda m: m.read(args.address, args.register, args.registers),
                 show)


def run_write(args: argparse.Namespace) -> int:
    with _master(args) as m:
        m.write(args.address, args.register, args.values)
    opt.emit(args, {"event": "written", "address": args.address, "register": args.register,
                "written": args.values},
             f"wrote {opt.plural(len(args.values), 'register')} from {args.register}")
    return 0


def run_set(args: argparse.Namespace) -> int:
    command: Union[int, str] = args.command
    try:
        command = int(args.command, 0)
    except ValueError:
        pass
    with _master(args) as m:
        m.set(args.address, command)
    opt.emit(args, {"event": "set", "address": args.address, "set": args.command},
             f"set {args.command}: done")
    return 0


def run_error_word(args: argparse.Namespace) -> int:
    from fap_py.g485 import describe_error_word

    def show(word: int) -> Tuple[Dict[str, Any], str]:
        return ({"error_word": word, "text": describe_error_word(word)},
                f"0x{word:04x} ({describe_error_word(word)})")

    return _poll(args, "read", lambda m: m.error_word(args.address), show)


def run_handshake(args: argparse.Namespace) -> int:
    return _poll(args, "handshake", lambda m: m.handshake(args.address),
                 lambda check: ({"check": check}, f"0x{check:02x}"))


def run_scan(args: argparse.Namespace) -> int:
    from fap_py.g485 import G485Error

    lo, hi = PROTOCOL.node_min, PROTOCOL.node_max
    if not lo <= args.first <= args.last <= hi:
        raise opt.UsageError(f"need {lo} <= --first <= --last <= {hi}, not {args.first}..{args.last}")
    with _master(args) as m:
        def probe(address: int):
            # G485 replies carry no address: a late reply could be credited to
            # the next ID. master.scan discards stale input and confirms a hit
            # by reading register 7 (the ID) back.
            try:
                return address if m.scan([address]) else None
            except G485Error:
                return None

        result = scan(list(range(args.first, args.last + 1)), probe, label="G485 ID",
                      progress=not args.json,
                      found=lambda a, _: opt.emit(args, {"event": "found", "address": a},
                                                  f"device {a} answers (ID register confirms)"))
    return scan_summary(args, result, args.last - args.first + 1, "IDs")
