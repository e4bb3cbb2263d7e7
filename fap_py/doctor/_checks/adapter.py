"""The adapter: FTDI latency timer (``adapter.latency``), RS-485 ioctl support and
the direction mode that fits (``adapter.rs485``, `fap ports`' verdict) and the
port's current termios against ``--baud`` (``port.termios``, this machine only)."""
from __future__ import annotations

import os
import termios
from typing import Any, Dict, Iterator, Optional

from .._context import Context, PortInfo
from .._finding import Finding
from .._registry import check

#: drivers without TIOCSRS485 (USB adapters: direction by the transceiver or RTS)
NO_RS485_DRIVERS = {"ftdi_sio", "ch341", "ch343", "cp210x", "pl2303", "cdc_acm", "usb_serial_simple"}
#: a 16550 reports a config it cannot set
READ_ONLY_DRIVERS = {"serial8250", "serial"}


@check("adapter.latency", "an FTDI adapter hands bytes on at once (latency timer 1 ms)")
def latency(ctx: Context) -> Iterator[Finding]:
    for port in ctx.ports():
        lt = port.sysfs.latency_timer_ms if port.sysfs else None
        if lt is None:
            continue
        path = f"/sys/class/tty/{port.name}/device/latency_timer"
        if lt <= 1:
            yield Finding("adapter.latency", "ok", f"latency timer {lt} ms", [f"{path}: {lt}"],
                          port=port.device)
            continue
        yield Finding("adapter.latency", "warning",
                      f"the FTDI latency timer is {lt} ms: a short reply waits up to {lt} ms in "
                      "the adapter (timeouts, slow polling)", [f"{path}: {lt}"],
                      f"echo 1 | sudo tee {path}\nfor good: /etc/udev/rules.d/99-fap-ftdi.rules:\n"
                      'ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", '
                      'ATTR{latency_timer}="1"', port=port.device)


def probe(ctx: Context, port: PortInfo) -> Dict[str, Any]:
    """`fap ports`' probe of the port (cached; ``Context.prober``): RS-485 state, baud, busy."""
    cache = ctx.__dict__.setdefault("_probes", {})
    if port.device not in cache:
        cache[port.device] = ctx.prober(port.device) if ctx.prober else {"rs485": "unknown"}
    return cache[port.device]


def _is_pty(ctx: Context, port: PortInfo) -> bool:
    st = ctx.stat(port.device)
    return st is not None and ctx.live and 136 <= os.major(st.st_rdev) <= 143


@check("adapter.rs485", "the RS-485 direction: kernel support and the mode that fits")
def rs485(ctx: Context) -> Iterator[Finding]:
    for port in ctx.ports():
        if not ctx.exists(port.device):
            continue
        driver = port.sysfs.driver if port.sysfs else None
        ev = [f"driver {driver}"] if driver else []
        if ctx.probe:
            info = probe(ctx, port)
            verdict = info.get("rs485", "unknown")
            ev.append(f"fap ports: rs485 {verdict}" + (f" ({info['error']})" if info.get("error") else ""))
        else:
            verdict = "no" if driver in NO_RS485_DRIVERS else \
                "read-only" if driver in READ_ONLY_DRIVERS else "unknown"
            ev.append(f"not probed under --root: by driver, rs485 {verdict}")
        check_fix = f"fap ports --check {port.asked} times the direction release"
        if verdict == "yes":
            yield Finding("adapter.rs485", "ok", "kernel RS-485 (TIOCSRS485): use --rs485 kernel",
                          ev, check_fix, port=port.device)
        elif verdict == "read-only":
            yield Finding("adapter.rs485", "info", "the UART reports RS-485 but cannot set it: "
                          "--rs485 soft (RTS by the library) or an auto-direction transceiver",
                          ev, f"--rs485 soft; {check_fix}", port=port.device)
        elif verdict == "no" and _is_pty(ctx, port):
            yield Finding("adapter.rs485", "info", "a pseudo-terminal: no RS-485 line, use --rs485 none",
                          ev, "--rs485 none", port=port.device)
        elif verdict == "no":
            yield Finding("adapter.rs485", "info",
                          "no kernel RS-485 ioctls (TIOCSRS485 refused): programs that need them "
                          "(mbusd, --rs485 kernel) fail; the direction must come from RTS or the "
                          "transceiver", ev, f"--rs485 soft (RTS) or --rs485 none with an "
                          f"auto-direction transceiver; {check_fix}", port=port.device)
        elif verdict == "busy":
            yield Finding("adapter.rs485", "warning", "busy: another program holds the port "
                          "(not opened; see port.holder)", ev, port=port.device)
        else:
            yield Finding("adapter.rs485", "info", "RS-485 support unknown", ev, check_fix,
                          port=port.device)


_BAUDS = {getattr(termios, f"B{b}"): b for b in
          (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400,
           57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000, 1500000,
           2000000, 2500000, 3000000, 3500000, 4000000) if hasattr(termios, f"B{b}")}


def read_termios(path: str) -> Optional[list]:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        return termios.tcgetattr(fd)
    except termios.error:
        return None
    finally:
        os.close(fd)


@check("port.termios", "the port's line settings (this machine only)")
def port_termios(ctx: Context) -> Iterator[Finding]:
    if not ctx.live or not ctx.probe:
        return
    for port in ctx.ports():
        if not ctx.exists(port.device) or probe(ctx, port).get("rs485") == "busy":
            continue
        attrs = read_termios(port.device)
        if attrs is None:
            continue
        iflag, _oflag, cflag = attrs[0], attrs[1], attrs[2]
        baud = _BAUDS.get(attrs[5], 0)
        bits = {termios.CS5: 5, termios.CS6: 6, termios.CS7: 7, termios.CS8: 8}[cflag & termios.CSIZE]
        parity = "N" if not cflag & termios.PARENB else ("O" if cflag & termios.PARODD else "E")
        stop = 2 if cflag & termios.CSTOPB else 1
        line = f"{port.device}: {baud} baud {bits}{parity}{stop}" + \
            (" crtscts" if cflag & termios.CRTSCTS else "") + \
            (" ixon" if iflag & termios.IXON else "") + (" ixoff" if iflag & termios.IXOFF else "")
        if ctx.baud and baud != ctx.baud:
            yield Finding("port.termios", "warning",
                          f"the port is at {baud} baud, not the {ctx.baud} asked: a program that "
                          "opens it without setting the rate talks at the wrong speed",
                          [line], f"stty -F {port.device} {ctx.baud} raw -echo "
                          "(fap commands set it themselves: --baud)", port=port.device)
        elif cflag & termios.CRTSCTS:
            yield Finding("port.termios", "warning",
                          "hardware flow control (crtscts) is on: without CTS wired, writes stall",
                          [line], f"stty -F {port.device} -crtscts", port=port.device)
        elif iflag & (termios.IXON | termios.IXOFF):
            yield Finding("port.termios", "info",
                          "XON/XOFF is on: bytes 0x11/0x13 of binary frames are taken as flow control",
                          [line], f"stty -F {port.device} -ixon -ixoff", port=port.device)
        else:
            yield Finding("port.termios", "ok", "line settings: " + line.split(": ", 1)[1],
                          [line], port=port.device)
