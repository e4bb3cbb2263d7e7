"""Services that take serial ports: brltty (``brltty``), ModemManager
(``modemmanager``), a getty (``getty.unit``) and the kernel console
(``console.cmdline``)."""
from __future__ import annotations

import re
from typing import Iterator, List, Tuple

from .._context import Context
from .._finding import Finding
from .._registry import check
from ._common import TTY_NAME_RE, USB_NAME_RE

UDEV_DIRS = ("/etc/udev/rules.d", "/run/udev/rules.d", "/lib/udev/rules.d", "/usr/lib/udev/rules.d")
#: USB serial adapters brltty's udev rules claim as braille displays
BRLTTY_IDS = {"1a86:7523": "CH340", "10c4:ea60": "CP210x", "0403:6001": "FT232"}


def _udev_rules(ctx: Context) -> List[Tuple[str, str]]:
    out = []
    for d in UDEV_DIRS:
        for name in ctx.listdir(d):
            if name.endswith(".rules"):
                text = ctx.read(f"{d}/{name}", 262144)
                if text is not None:
                    out.append((f"{d}/{name}", text))
    return out


@check("brltty", "brltty does not claim USB serial adapters")
def brltty(ctx: Context) -> Iterator[Finding]:
    installed = [u.path for n, u in ctx.units().items() if n.startswith("brltty")]
    installed += [p for p, _ in _udev_rules(ctx) if "brltty" in p]
    log = [(n, ln) for n, ln in enumerate(ctx.kernel_log(), 1) if "brltty" in ln]
    adapters = [(p.name, p.vid_pid) for p in ctx.all_ports() if p.vid_pid in BRLTTY_IDS]
    fix = ("sudo systemctl mask brltty.service brltty-udev.service && "
           "sudo ln -s /dev/null /etc/udev/rules.d/85-brltty.rules   # or: sudo apt remove brltty; "
           "then replug the adapter")
    if log:
        yield Finding("brltty", "error",
                      "brltty took the USB serial adapter (it claims CH340, CP210x and FT232 ids "
                      "as braille displays): the tty vanishes right after plug-in",
                      [f"{ctx.kernel_log_source}:{n}: {ln.strip()[:200]}" for n, ln in log[:4]]
                      + installed[:3], fix)
    elif installed and adapters:
        yield Finding("brltty", "warning",
                      f"brltty is installed and {adapters[0][0]} is a "
                      f"{BRLTTY_IDS[adapters[0][1] or '']} ({adapters[0][1]}) it claims",
                      installed[:3] + [f"/sys/class/tty/{n}: usb {v}" for n, v in adapters], fix)
    elif installed:
        yield Finding("brltty", "info", "brltty is installed: it claims CH340, CP210x and FT232 "
                      "adapters when they are plugged in", installed[:3], fix)
    else:
        yield Finding("brltty", "ok", "brltty is not installed")


def _mm_ignored(ctx: Context, vid_pid: str) -> str:
    vid = vid_pid.split(":")[0]
    for path, text in _udev_rules(ctx):
        for n, line in enumerate(text.splitlines(), 1):
            if "ID_MM_DEVICE_IGNORE" in line and not line.lstrip().startswith("#") and \
                    (vid in line or "idVendor" not in line):
                return f"{path}:{n}: {line.strip()[:160]}"
    return ""


@check("modemmanager", "ModemManager leaves the serial adapters alone")
def modemmanager(ctx: Context) -> Iterator[Finding]:
    enabled, ev = ctx.unit_enabled("ModemManager.service")
    if not enabled:
        yield Finding("modemmanager", "ok", "ModemManager is not enabled", [ev])
        return
    for port in ctx.ports():
        if not USB_NAME_RE.match(port.name):
            continue
        vid_pid = port.sysfs.vid_pid if port.sysfs and port.sysfs.vid_pid else "VVVV:PPPP"
        ignored = _mm_ignored(ctx, vid_pid)
        if ignored:
            yield Finding("modemmanager", "ok", f"ModemManager is told to ignore {port.name}",
                          [ev, ignored], port=port.device)
            continue
        vid, pid = vid_pid.split(":")
        yield Finding("modemmanager", "warning",
                      f"ModemManager is enabled and probes new {port.name[:6]} ports with AT "
                      "commands for some seconds after plug-in (bytes on the bus, the port busy)",
                      [ev, f"{port.device}: usb {vid_pid}", "no udev rule sets ID_MM_DEVICE_IGNORE"],
                      "/etc/udev/rules.d/99-fap-mm-ignore.rules:\n"
                      f'ATTRS{{idVendor}}=="{vid}", ATTRS{{idProduct}}=="{pid}", '
                      'ENV{ID_MM_DEVICE_IGNORE}="1"\n'
                      "then `sudo udevadm control --reload && sudo udevadm trigger` "
                      "(or `sudo systemctl disable --now ModemManager`)", port=port.device)


def _port_names(ctx: Context) -> List[Tuple[str, str]]:
    """(name, device) of every checked port, also as serial0/serial1 when those link to it."""
    out = [(p.name, p.device) for p in ctx.ports()]
    for alias in ("serial0", "serial1"):
        canon = ctx.canonical(f"/dev/{alias}")
        if canon and ctx.readlink(f"/dev/{alias}") is not None:
            out += [(alias, d) for n, d in list(out) if d == canon]
    return out


@check("getty.unit", "no getty runs on the port")
def getty_unit(ctx: Context) -> Iterator[Finding]:
    for name, device in _port_names(ctx):
        if not TTY_NAME_RE.match(name):
            continue        # serial0 (its target is checked), a pty
        for unit in (f"serial-getty@{name}.service", f"getty@{name}.service"):
            enabled, ev = ctx.unit_enabled(unit)
            if enabled:
                yield Finding("getty.unit", "error",
                              f"{unit} is enabled: a login prompt owns {device} and answers "
                              "the bus", [ev],
                              f"sudo systemctl disable --now {unit} && sudo systemctl mask {unit}",
                              port=device)
                break
        else:
            yield Finding("getty.unit", "ok", f"no getty enabled on {name}", port=device)


_CONSOLE_RE = re.compile(r"(?<!\S)console=([^\s,]+)(,\S*)?")


@check("console.cmdline", "the kernel console is not on the port")
def console_cmdline(ctx: Context) -> Iterator[Finding]:
    sources = [("/proc/cmdline", ctx.read("/proc/cmdline", 65536))]
    for p in ("/boot/firmware/cmdline.txt", "/boot/cmdline.txt"):
        sources.append((p, ctx.read(p, 65536)))
    names = _port_names(ctx)
    reported = set()
    for path, text in sources:
        if not text:
            continue
        for m in _CONSOLE_RE.finditer(text):
            for name, device in names:
                if m.group(1) != name or device in reported:
                    continue
                reported.add(device)
                if path == "/proc/cmdline":
                    where = ("/boot/firmware/cmdline.txt (a Raspberry Pi) or GRUB_CMDLINE_LINUX in "
                             "/etc/default/grub, then `sudo update-grub`")
                else:
                    where = path
                yield Finding("console.cmdline", "error",
                              f"the kernel console is on {device}: boot messages and a login "
                              "go out on the bus", [f"{path}: {m.group(0)}"],
                              f"remove `{m.group(0)}` from {where}; reboot "
                              "(on a Pi: `sudo raspi-config nonint do_serial_cons 1`)", port=device)
    for _, device in names:
        if device not in reported:
            yield Finding("console.cmdline", "ok", "the kernel console is elsewhere", port=device)
