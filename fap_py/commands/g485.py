"""``fap g485``: run simulated G485 devices on a port, or talk to devices as the master.

    fap g485 sim --port /dev/pts/3 --address 1 --address 2 --eeprom-dir /tmp/g485
    fap g485 read --port /dev/ttyUSB0 --address 1 --register 1 --count 7
    fap g485 write --port /dev/ttyUSB0 --address 1 --register 8 0x32 0x10
    fap g485 set --port /dev/ttyUSB0 --address 1 save_eeprom
    fap g485 error-word --port /dev/ttyUSB0 --address 1
    fap g485 handshake --port /dev/ttyUSB0 --address 1
    fap g485 scan --port /dev/ttyUSB0 --rs485 soft
"""
from __future__ import annotations

import argparse
import os
import signal
import threading
from typing import Any


def _int(text: str) -> int:
    return int(text, 0)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("g485", help="Gicren G485: device simulator and master transactions")
    cmds = p.add_subparsers(dest="g485_command", metavar="ACTION", required=True)

    def common(q: argparse.ArgumentParser, master: bool = True) -> None:
        q.add_argument("--port", required=True, help="device path or pyserial URL")
        q.add_argument("--baud", type=int, default=115200)
        q.add_argument("--rs485", choices=["auto", "kernel", "soft", "none"], default="auto",
                       help="direction control of a device path (default: %(default)s)")
        q.add_argument("--rts-before", type=float, default=0.0, metavar="MS", help="RTS lead, ms")
        q.add_argument("--rts-after", type=float, default=0.0, metavar="MS", help="RTS tail, ms")
        q.add_argument("--rts-polarity", choices=["high", "low"], default="high")
        if master:
            q.add_argument("--address", type=_int, required=True, help="device ID 1..126 (0 = broadcast)")
            q.add_argument("--timeout", type=float, default=0.1, help="reply timeout, seconds")
            q.add_argument("--retries", type=int, default=2)
            q.add_argument("--check", choices=["handshake", "reread", "none"], default="handshake")

    s = cmds.add_parser("sim", help="simulate devices on a port until interrupted")
    common(s, master=False)
    s.add_argument("--address", type=_int, action="append", required=True,
                   help="a device ID to simulate (repeat for several devices)")
    s.add_argument("--eeprom-dir", help="keep each device's EEPROM in DIR/g485-<ID>.json")
    s.add_argument("--wake-up-loss", action="store_true",
                   help="lose the first burst after power-on/reset (baud detection)")
    s.add_argument("--seed", type=int, default=0, help="seed of bulk-mode discards")
    s.set_defaults(func=run_sim)

    c = cmds.add_parser("scan", help="list the IDs that answer (each confirmed by reading its ID register)")
    common(c, master=False)
    c.add_argument("--timeout", type=float, default=0.02, help="reply timeout per ID, seconds")
    c.add_argument("--retries", type=int, default=0)
    c.add_argument("--first", type=_int, default=1)
    c.add_argument("--last", type=_int, default=126)
    c.set_defaults(func=run_scan)

    r = cmds.add_parser("read", help="read registers")
    common(r)
    r.add_argument("--register", type=_int, required=True)
    r.add_argument("--count", type=_int, default=1)
    r.set_defaults(func=run_read)

    w = cmds.add_parser("write", help="write registers")
    common(w)
    w.add_argument("--register", type=_int, required=True)
    w.add_argument("values", type=_int, nargs="+")
    w.set_defaults(func=run_write)

    t = cmds.add_parser("set", help="send a Set command (factory_reset, save_eeprom, reset, ...)")
    common(t)
    t.add_argument("command", help="SetCommand name or value")
    t.set_defaults(func=run_set)

    e = cmds.add_parser("error-word", help="read the error word")
    common(e)
    e.set_defaults(func=run_error_word)

    h = cmds.add_parser("handshake", help="read the device's check byte")
    common(h)
    h.set_defaults(func=run_handshake)


def run_sim(args: argparse.Namespace) -> int:
    from fap_py.g485 import SimDevice, Simulator

    devices = []
    for address in args.address:
        path = os.path.join(args.eeprom_dir, f"g485-{address}.json") if args.eeprom_dir else None
        if args.eeprom_dir:
            os.makedirs(args.eeprom_dir, exist_ok=True)
        devices.append(SimDevice(address, eeprom_path=path, wake_up_loss=args.wake_up_loss,
                                 seed=args.seed + address))
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    with Simulator(args.port, devices, baudrate=args.baud, rs485=_rs485(args)) as sim:
        print(f"simulating G485 devices {', '.join(map(str, args.address))} on {sim.name}", flush=True)
        while not done.wait(0.5):
            if sim.error is not None:
                raise sim.error
    return 0


def _rs485(args: argparse.Namespace):
    """Line options for a device path (None for a pyserial URL: it has its own)."""
    from fap_py.fap import RS485, RS485Mode

    if "://" in args.port:
        return None
    mode = {"auto": RS485Mode.AUTO, "kernel": RS485Mode.KERNEL, "soft": RS485Mode.SOFT_RTS,
            "none": RS485Mode.NONE}[args.rs485]
    return RS485(mode=mode, rts_active_high=args.rts_polarity == "high",
                 delay_before_send_us=round(args.rts_before * 1000), delay_after_send_us=round(args.rts_after * 1000))


def _master(args: argparse.Namespace, **kwargs: Any):
    from fap_py.g485 import G485Master

    kwargs.setdefault("check", getattr(args, "check", "handshake"))
    return G485Master(args.port, args.baud, timeout=args.timeout, retries=args.retries, rs485=_rs485(args),
                      **kwargs)


def run_scan(args: argparse.Namespace) -> int:
    with _master(args) as m:
        found = m.scan(range(args.first, args.last + 1))
    print(" ".join(map(str, found)) if found else "no device answered")
    return 0 if found else 1


def run_read(args: argparse.Namespace) -> int:
    with _master(args) as m:
        data = m.read(args.address, args.register, args.count)
    for i, value in enumerate(data):
        print(f"register {args.register + i}: {value} (0x{value:02x})")
    return 0


def run_write(args: argparse.Namespace) -> int:
    with _master(args) as m:
        m.write(args.address, args.register, args.values)
    return 0


def run_set(args: argparse.Namespace) -> int:
    command: object = args.command
    try:
        command = int(args.command, 0)
    except ValueError:
        pass
    with _master(args) as m:
        m.set(args.address, command)  # type: ignore[arg-type]
    return 0


def run_error_word(args: argparse.Namespace) -> int:
    from fap_py.g485 import describe_error_word

    with _master(args) as m:
        word = m.error_word(args.address)
    print(f"0x{word:04x} ({describe_error_word(word)})")
    return 0


def run_handshake(args: argparse.Namespace) -> int:
    with _master(args) as m:
        print(f"0x{m.handshake(args.address):02x}")
    return 0
