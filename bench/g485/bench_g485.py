#!/usr/bin/env python3
"""G485 read transactions/s against the simulator, side by side with peers.

One run, same link for everyone: a 2-port fap_py virtual bus (unpaced by
default, ``--paced`` paces it at --baud), the client in this process (main
thread), the server in its own process so CPU time is attributable:

* fap_py.g485 master, 10 registers per read, with check operation "none"
  (one round trip, like the peers) and "handshake" (the default: two round
  trips) against ``fap g485 sim``, both going through libfap's C port layer;
  and the asyncio master (no worker thread: the event loop drives it);
* minimalmodbus and pymodbus (sync and async) RTU reads of 10 holding
  registers against a pymodbus RTU server;
* dynamixel-sdk protocol 1.0 reads of 10 bytes against a small Dynamixel 1.0
  responder written here (``--serve dxl``);
* two reference rows without any protocol (``--serve canned``): bare Python
  write/poll/read and write/spin/read, the floor of a blocking and of a
  busy-waiting client on this link.

Client CPU is the main thread's CPU time (the bus relay thread is not
counted); server CPU is read from /proc. A last table shows what a read to
an absent device costs in CPU (busy-waiting shows up there).

    /tmp/venv-g485/bin/python bench/g485/bench_g485.py --seconds 3
"""
from __future__ import annotations

import argparse
import asyncio
import logging
import os
import select
import subprocess
import sys
import tempfile
import time
import tty
from typing import Any, Callable, Dict, List, Optional, Tuple

REGS = 10
CLK_TCK = os.sysconf("SC_CLK_TCK")


# -- servers (run in a child process) --------------------------------------------

def serve_modbus(path: str, baud: int) -> None:
    """pymodbus RTU server, device 1, 100 holding registers."""
    from pymodbus import FramerType
    from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
    from pymodbus.server import StartSerialServer

    logging.disable(logging.WARNING)  # its deprecation notice
    context = ModbusServerContext(devices={1: ModbusDeviceContext(
        hr=ModbusSequentialDataBlock(1, list(range(100))))}, single=False)
    print("ready", flush=True)
    StartSerialServer(context=context, framer=FramerType.RTU, port=path, baudrate=baud,
                      ignore_missing_devices=True)


def _dxl_status(ident: int, error: int, params: bytes) -> bytes:
    body = bytes((ident, len(params) + 2, error)) + params
    return b"\xff\xff" + body + bytes((~sum(body) & 0xFF,))


def serve_dxl(path: str, ident: int = 1) -> None:
    """A minimal Dynamixel protocol 1.0 device: PING, READ_DATA, WRITE_DATA on a 256-byte table."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    table = bytearray(i & 0xFF for i in range(256))
    buf = bytearray()
    print("ready", flush=True)
    while True:
        select.select([fd], [], [])
        buf += os.read(fd, 4096)
        while True:
            i = buf.find(b"\xff\xff")
            if i < 0:
                del buf[:len(buf) - 1 if buf[-1:] == b"\xff" else len(buf)]
                break
            if len(buf) < i + 4:
                del buf[:i]
                break
            length = buf[i + 3]
            if buf[i + 2] == 0xFF or length < 2:
                del buf[:i + 1]
                continue
            end = i + 4 + length
            if len(buf) < end:
                del buf[:i]
                break
            pkt = bytes(buf[i:end])
            del buf[:end]
            if ~sum(pkt[2:-1]) & 0xFF != pkt[-1] or pkt[2] != ident:
                continue
            inst, params = pkt[4], pkt[5:-1]
            if inst == 0x01:
                os.write(fd, _dxl_status(ident, 0, b""))
            elif inst == 0x02 and len(params) == 2:
                addr, n = params
                os.write(fd, _dxl_status(ident, 0, bytes(table[addr:addr + n])))
            elif inst == 0x03 and params:
                addr = params[0]
                table[addr:addr + len(params) - 1] = params[1:]
                os.write(fd, _dxl_status(ident, 0, b""))


def serve_canned(path: str) -> None:
    """Reference responder: answers every 7 bytes received with 16 fixed bytes (no protocol at all)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    reply = _dxl_status(1, 0, bytes(REGS))
    pending = 0
    print("ready", flush=True)
    while True:
        select.select([fd], [], [])
        pending += len(os.read(fd, 4096))
        while pending >= 7:  # a paced bus delivers a request in pieces
            pending -= 7
            os.write(fd, reply)


# -- clients ----------------------------------------------------------------------

def bare_client(path: str, spin: bool) -> Tuple[Reader, Callable[[], None], Optional[Reader]]:
    """Reference client: write 7 bytes, wait (poll, or spin on non-blocking reads), read 16.

    No protocol work at all: what Python itself costs on this link, blocking
    or busy-waiting. Not a library; it shows where the floor is.
    """
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(fd)
    poller = select.poll()
    poller.register(fd, select.POLLIN)
    request = bytes(7)
    size = 6 + REGS

    def read() -> None:
        os.write(fd, request)
        got = b""
        while len(got) < size:
            if not spin and not poller.poll(500):
                raise TimeoutError("no reply")
            try:
                got += os.read(fd, size - len(got))
            except BlockingIOError:
                pass

    return read, lambda: os.close(fd), None


Reader = Callable[[], None]


def g485_client(path: str, baud: int, check: str) -> Tuple[Reader, Callable[[], None], Reader]:
    from fap_py.g485 import G485Master

    m = G485Master(path, baud, timeout=0.5, check=check)

    def read() -> None:
        data = m.read(1, 1, REGS)
        assert len(data) == REGS

    def read_absent() -> None:
        try:
            m.read(99, 1, REGS, timeout=0.05, retries=0)
        except Exception:
            pass

    return read, m.close, read_absent


def minimalmodbus_client(path: str, baud: int) -> Tuple[Reader, Callable[[], None], Optional[Reader]]:
    import minimalmodbus

    inst = minimalmodbus.Instrument(path, 1)
    inst.serial.baudrate = baud
    inst.serial.timeout = 0.5
    absent = minimalmodbus.Instrument(path, 99)
    absent.serial.timeout = 0.05

    def read() -> None:
        assert len(inst.read_registers(0, REGS)) == REGS

    def read_absent() -> None:
        try:
            absent.read_registers(0, REGS)
        except Exception:
            pass

    return read, inst.serial.close, read_absent


def pymodbus_sync_client(path: str, baud: int) -> Tuple[Reader, Callable[[], None], Optional[Reader]]:
    from pymodbus.client import ModbusSerialClient

    client = ModbusSerialClient(path, baudrate=baud, timeout=0.5, retries=0)
    client.connect()

    def read() -> None:
        rr = client.read_holding_registers(0, count=REGS, device_id=1)
        assert not rr.isError() and len(rr.registers) == REGS

    return read, client.close, None


def dynamixel_client(path: str, baud: int) -> Tuple[Reader, Callable[[], None], Optional[Reader]]:
    from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

    port = PortHandler(path)
    if not port.openPort() or not port.setBaudRate(baud):
        raise RuntimeError("dynamixel-sdk could not open the port")
    packet = PacketHandler(1.0)

    def read() -> None:
        data, result, error = packet.readTxRx(port, 1, 0, REGS)
        assert result == COMM_SUCCESS and len(data) == REGS, (result, error)

    def read_absent() -> None:
        packet.readTxRx(port, 99, 0, REGS)

    return read, port.closePort, read_absent


# -- measurement ------------------------------------------------------------------

def proc_cpu(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def start_server(argv: List[str]) -> subprocess.Popen:
    # in a neutral folder: from the repository root ``-m fap_py`` would be the
    # checkout's fap_py/, which has no compiled _native (a non-editable install)
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())
    line = proc.stdout.readline() if proc.stdout else ""
    if not line:
        raise RuntimeError(f"server {argv} did not start")
    return proc


def warm_up(read: Reader, seconds: float = 10.0) -> None:
    deadline = time.monotonic() + seconds
    ok = 0
    while ok < 50:
        try:
            read()
            ok += 1
        except Exception:
            if time.monotonic() > deadline:
                raise


def run_pair(server_argv: List[str], client: Callable[[], Tuple[Reader, Callable[[], None], Any]],
             seconds: float) -> Dict[str, float]:
    """Start the server program, open the client (``client()``: read, close,
    ...), warm up, measure, stop both: :func:`measure`'s result."""
    srv = start_server(server_argv)
    try:
        read, close, _ = client()
        try:
            warm_up(read)
            return measure(read, seconds, srv.pid)
        finally:
            close()
    finally:
        srv.terminate()
        srv.wait(10)
        if srv.stdout:
            srv.stdout.close()


def measure(read: Reader, seconds: float, server_pid: int) -> Dict[str, float]:
    n = errors = 0
    s0 = proc_cpu(server_pid)
    c0 = time.thread_time()
    t0 = time.perf_counter()
    end = t0 + seconds
    while True:
        for _ in range(50):
            try:
                read()
            except Exception:  # a failed read counts, it does not stop the run
                errors += 1
        n += 50
        if time.perf_counter() >= end:
            break
    wall = time.perf_counter() - t0
    cpu = time.thread_time() - c0
    scpu = proc_cpu(server_pid) - s0
    ok = max(1, n - errors)
    return {"n": n, "rate": ok / wall, "client_us": cpu / ok * 1e6, "server_us": scpu / ok * 1e6,
            "client_load": cpu / wall, "errors": errors}


async def g485_async_measure(path: str, baud: int, seconds: float, server_pid: int) -> Dict[str, float]:
    from fap_py.g485.aio import AsyncG485Master

    async with AsyncG485Master(path, baud, timeout=0.5, check="none") as bus:
        for _ in range(50):
            await bus.read(1, 1, REGS)
        n = 0
        s0 = proc_cpu(server_pid)
        c0 = time.thread_time()  # the event loop's thread: the async master has no worker thread
        t0 = time.perf_counter()
        end = t0 + seconds
        errors = 0
        while time.perf_counter() < end:
            try:
                assert len(await bus.read(1, 1, REGS)) == REGS
            except Exception:
                errors += 1
            n += 1
        wall = time.perf_counter() - t0
        cpu = time.thread_time() - c0
        scpu = proc_cpu(server_pid) - s0
    ok = max(1, n - errors)
    return {"n": n, "rate": ok / wall, "client_us": cpu / ok * 1e6, "server_us": scpu / ok * 1e6,
            "client_load": cpu / wall, "errors": errors}


async def pymodbus_async_measure(path: str, baud: int, seconds: float, server_pid: int) -> Dict[str, float]:
    from pymodbus.client import AsyncModbusSerialClient

    client = AsyncModbusSerialClient(path, baudrate=baud, timeout=0.5, retries=0)
    await client.connect()
    ok, deadline = 0, time.monotonic() + 10.0
    while ok < 50:  # warm-up: the server may still be opening its port
        try:
            rr = await client.read_holding_registers(0, count=REGS, device_id=1)
            ok += not rr.isError()
        except Exception:
            if time.monotonic() > deadline:
                raise
    n = 0
    s0 = proc_cpu(server_pid)
    c0 = time.thread_time()
    t0 = time.perf_counter()
    end = t0 + seconds
    errors = 0
    while time.perf_counter() < end:
        try:
            rr = await client.read_holding_registers(0, count=REGS, device_id=1)
            assert not rr.isError() and len(rr.registers) == REGS
        except Exception:
            errors += 1
        n += 1
    wall = time.perf_counter() - t0
    cpu = time.thread_time() - c0
    scpu = proc_cpu(server_pid) - s0
    client.close()
    ok = max(1, n - errors)
    return {"n": n, "rate": ok / wall, "client_us": cpu / ok * 1e6, "server_us": scpu / ok * 1e6,
            "client_load": cpu / wall, "errors": errors}


def absent_cost(read_absent: Optional[Reader], tries: int = 5) -> Optional[Tuple[float, float]]:
    """(wall ms, CPU ms) of one read addressed to a device that does not exist."""
    if read_absent is None:
        return None
    c0, t0 = time.thread_time(), time.perf_counter()
    for _ in range(tries):
        read_absent()
    return ((time.perf_counter() - t0) / tries * 1e3, (time.thread_time() - c0) / tries * 1e3)


def wire_limit(request: int, reply: int, baud: int, gap_chars: float = 0.0) -> float:
    """Transactions/s the wire allows at ``baud`` (10 bits per byte, no turnaround)."""
    return baud / (10.0 * (request + reply + gap_chars))


def run_one(args: argparse.Namespace, rnd: int, server_argv: List[str],
            make_client: object) -> Tuple[Dict[str, float], Optional[Tuple[float, float]]]:
    """One library, one round, on a fresh bus: (measurement, absent-ID cost or None)."""
    from fap_py.vbus import VirtualBus

    absent = None
    with VirtualBus(ports=2, baud=args.baud if args.paced else None, seed=1) as bus:
        server = start_server(server_argv + [bus.paths[1]])
        try:
            if isinstance(make_client, str):
                coro = g485_async_measure if make_client == "async-g485" else pymodbus_async_measure
                res = asyncio.run(coro(bus.paths[0], args.baud, args.seconds, server.pid))
            else:
                read, close, read_absent = make_client(bus.paths[0])  # type: ignore[operator]
                try:
                    warm_up(read)
                    res = measure(read, args.seconds, server.pid)
                    absent = absent_cost(read_absent) if rnd == 0 else None
                finally:
                    close()
        finally:
            server.terminate()
            server.wait(5)
            if server.stdout:
                server.stdout.close()
    return res, absent


def paired(args: argparse.Namespace) -> int:
    """The sync and async G485 masters and the bare poll client in interleaved batches, each on
    its own bus: ``paired.py``, the measurement ``python -m bench`` reports as its G485 targets
    (with ``--paced``, the same setup). Run as its own program: paired.py imports this module,
    this one never imports paired.py (no import circle)."""
    argv = [sys.executable, os.path.join(os.path.dirname(os.path.abspath(__file__)), "paired.py"),
            str(args.baud), "--rounds", str(args.rounds)]
    argv += [] if args.paced else ["--unpaced"]
    argv += ["--batch", str(args.batch)] if args.batch else []
    return subprocess.call(argv)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=2.0, help="measuring time per library and round")
    ap.add_argument("--rounds", type=int, default=3, help="rounds (libraries interleaved); medians shown")
    ap.add_argument("--baud", type=int, default=115200, help="nominal baud of every port")
    ap.add_argument("--paced", action="store_true", help="pace the virtual bus at --baud")
    ap.add_argument("--only", help="comma list: g485-none,g485-handshake,g485-async,dynamixel,"
                                   "minimalmodbus,pymodbus-sync,pymodbus-async,bare-block,bare-spin")
    ap.add_argument("--paired", action="store_true",
                    help="interleaved short batches of the sync and async G485 masters and the bare poll "
                         "client, --rounds of them: robust ratios on a loaded machine (with --paced: the "
                         "measurement python -m bench reports)")
    ap.add_argument("--batch", type=int, help="reads per batch with --paired (default: about 0.2 s of reads)")
    ap.add_argument("--serve", nargs=2, metavar=("KIND", "PATH"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.paired:
        return paired(args)

    if args.serve:
        kind, path = args.serve
        if kind == "modbus":
            serve_modbus(path, args.baud)
        elif kind == "dxl":
            serve_dxl(path)
        elif kind == "canned":
            serve_canned(path)
        return 0


    me = [sys.executable, os.path.abspath(__file__), "--baud", str(args.baud)]
    g485_server = [sys.executable, "-m", "fap_py", "g485", "sim", "--address", "1", "--baud", str(args.baud),
                   "--port"]
    runs = [
        ("g485-none", "fap_py.g485 check=none", g485_server, lambda p: g485_client(p, args.baud, "none"),
         wire_limit(7, 16, args.baud)),
        ("g485-handshake", "fap_py.g485 check=handshake", g485_server,
         lambda p: g485_client(p, args.baud, "handshake"), wire_limit(7 + 6, 16 + 7, args.baud)),
        ("g485-async", "fap_py.g485.aio check=none", g485_server, "async-g485",
         wire_limit(7, 16, args.baud)),
        ("dynamixel", "dynamixel-sdk 1.0", me + ["--serve", "dxl"], lambda p: dynamixel_client(p, args.baud),
         wire_limit(8, 16, args.baud)),
        ("minimalmodbus", "minimalmodbus RTU", me + ["--serve", "modbus"],
         lambda p: minimalmodbus_client(p, args.baud), wire_limit(8, 25, args.baud, 7)),
        ("pymodbus-sync", "pymodbus sync RTU", me + ["--serve", "modbus"],
         lambda p: pymodbus_sync_client(p, args.baud), wire_limit(8, 25, args.baud, 7)),
        ("pymodbus-async", "pymodbus async RTU", me + ["--serve", "modbus"], "async-pymodbus",
         wire_limit(8, 25, args.baud, 7)),
        ("bare-block", "(ref) bare poll, no protocol", me + ["--serve", "canned"],
         lambda p: bare_client(p, spin=False), wire_limit(7, 16, args.baud)),
        ("bare-spin", "(ref) bare spin, no protocol", me + ["--serve", "canned"],
         lambda p: bare_client(p, spin=True), wire_limit(7, 16, args.baud)),
    ]
    if args.only:
        wanted = set(args.only.split(","))
        runs = [r for r in runs if r[0] in wanted]

    rounds: Dict[str, List[Dict[str, float]]] = {key: [] for key, *_ in runs}
    lost: Dict[str, int] = {key: 0 for key, *_ in runs}  # rounds that could not run at all
    for rnd in range(args.rounds):
        for key, label, server_argv, make_client, limit in runs:
            try:
                res, absent = run_one(args, rnd, server_argv, make_client)
            except Exception as exc:  # one library's broken round must not stop the others
                lost[key] += 1
                print(f"  round {rnd + 1}: {label}: FAILED ({type(exc).__name__}: {exc})",
                      file=sys.stderr, flush=True)
                continue
            res.update(label=label, limit=limit, absent=absent)
            rounds[key].append(res)
            print(f"  round {rnd + 1}: {label}: {res['rate']:.0f}/s", file=sys.stderr, flush=True)

    results = []
    for key, label, *_ in runs:
        if not rounds[key]:
            print(f"{label}: failed in every round", file=sys.stderr)
            continue
        rs = sorted(rounds[key], key=lambda r: r["rate"])
        med = dict(rs[len(rs) // 2])
        med["low"], med["high"] = rs[0]["rate"], rs[-1]["rate"]
        med["absent"] = rounds[key][0]["absent"]
        med["errors"] = sum(r["errors"] for r in rs)
        if lost[key]:
            med["label"] = f"{label} [{len(rs)}/{args.rounds}]"
        results.append(med)

    link = f"virtual bus paced at {args.baud} baud" if args.paced else "virtual bus, unpaced ptys"
    print(f"\nG485 / peers: read of {REGS} registers, {link}, median of {args.rounds} rounds of "
          f"{args.seconds:g} s, python {sys.version.split()[0]}, {os.cpu_count()} CPUs")
    print(f"{'library':28} {'reads/s':>8} {'(min..max)':>13} {'client CPU':>11} {'client':>7} "
          f"{'server CPU':>11} {'wire limit':>11} {'absent ID read':>15} {'failed':>7}")
    print(f"{'':28} {'':>8} {'':>13} {'us/read':>11} {'load':>7} {'us/read':>11} "
          f"{'@' + str(args.baud):>11} {'wall/CPU ms':>15} {'reads':>7}")
    for r in results:
        absent = f"{r['absent'][0]:.1f}/{r['absent'][1]:.2f}" if r["absent"] else "n/a"
        spread = f"{r['low']:.0f}..{r['high']:.0f}"
        print(f"{r['label']:28} {r['rate']:8.0f} {spread:>13} {r['client_us']:11.1f} "
              f"{r['client_load']:6.0%} {r['server_us']:11.1f} {r['limit']:11.0f} {absent:>15} "
              f"{r['errors']:7d}")
    print("client load = client CPU time / wall time (100% = busy-waiting); wire limit = reads/s "
          "the bytes alone allow at the nominal baud (Modbus with its 3.5-char gaps)")
    print("failed reads = reads that raised (timeouts, ...), summed over the rounds; reads/s counts "
          "successful reads only")
    print("client CPU = the main thread's (the event loop's for the async rows); the bus relay thread "
          "is not counted")
    print("[n/N]: the library's reads failed for a whole round in N - n rounds (see stderr)")
    print("(ref) rows: no library, Python write + wait + read of fixed bytes against a canned responder: "
          "the floor of a blocking (poll) and of a busy-waiting (spin) client on this link")
    return 0


if __name__ == "__main__":
    sys.exit(main())
