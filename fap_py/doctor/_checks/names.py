"""The port's name: it exists (``port.exists``), a stable name to use instead of
``ttyUSBn`` (``names.by_id``) and identical adapters sharing one by-id name
(``names.shared``)."""
from __future__ import annotations

import os
from collections import defaultdict
from typing import Dict, Iterator, List

from .._context import Context
from .._finding import Finding
from .._registry import check
from ._common import USB_NAME_RE


@check("port.exists", "the port asked for exists")
def port_exists(ctx: Context) -> Iterator[Finding]:
    ctx.all_ports()
    if ctx.sysfs_problem:
        yield Finding("port.exists", "warning", "the copied /sys was not read: a file in it is "
                      "not what sysfs holds", [ctx.sysfs_problem],
                      "copy /sys again (`cp -rL` follows links into fifos and devices: copy "
                      "/sys/class/tty and the device directories with `tar`)")
    if ctx.asked_port is None:
        if not ctx.ports():
            yield Finding("port.exists", "info", "no serial port with a device behind it found",
                          [f"{ctx.root.rstrip('/')}/sys/class/tty: no port with a device link"],
                          "plug the adapter in and look at `dmesg | tail`; `fap ports --all`")
        return
    port = ctx.ports()[0]
    if ctx.exists(port.device):
        ev = [f"{port.asked} -> {port.device}"] if port.asked != port.device else [port.device]
        yield Finding("port.exists", "ok", f"{port.asked} exists", ev, port=port.device)
        return
    others = [f"/dev/{p.name}" for p in ctx.all_ports()]
    yield Finding("port.exists", "error", f"{port.asked} does not exist",
                  [f"{port.asked}: no such file"
                   + (f" (resolves to {port.device})" if port.device != port.asked else ""),
                   "ports here: " + (", ".join(others) or "none")],
                  "check the cable and `dmesg | tail` (a USB adapter that is not enumerated, "
                  "or one that took another name); `fap ports` lists the ports", port=port.asked)


def _by_path(ctx: Context, name: str) -> List[str]:
    out = []
    for link in ctx.listdir("/dev/serial/by-path"):
        t = ctx.readlink(f"/dev/serial/by-path/{link}")
        if t and os.path.basename(t) == name:
            out.append(f"/dev/serial/by-path/{link}")
    return out


def _analysed(ctx: Context, host_path: str) -> str:
    return "/dev/" + os.path.relpath(host_path, ctx.host("/dev") or "/dev")


@check("names.by_id", "a stable name for a USB port")
def names_by_id(ctx: Context) -> Iterator[Finding]:
    for port in ctx.ports():
        if not USB_NAME_RE.match(port.name) or port.sysfs is None:
            continue
        if port.sysfs.by_id:
            by_id = _analysed(ctx, port.sysfs.by_id)
            if port.asked.startswith("/dev/serial/"):
                yield Finding("names.by_id", "ok", f"{port.asked} is a stable name", port=port.device)
            else:
                yield Finding("names.by_id", "info",
                              f"{port.name} may be another adapter after a replug or reboot; "
                              f"{by_id} stays this one", [f"{by_id} -> {port.device}"],
                              f"--port {by_id}", port=port.device)
            continue
        paths = _by_path(ctx, port.name)
        fix = f"--port {paths[0]} (the USB socket's name)" if paths else (
            "a udev rule naming it, e.g. /etc/udev/rules.d/99-fap-names.rules:\n"
            f'SUBSYSTEM=="tty", ATTRS{{idVendor}}=="{(port.sysfs.vid_pid or "VVVV:").split(":")[0]}", '
            f'ATTRS{{idProduct}}=="{(port.sysfs.vid_pid or ":PPPP").split(":")[1]}", '
            'SYMLINK+="rs485-bus"')
        yield Finding("names.by_id", "warning",
                      f"{port.name} has no /dev/serial/by-id name (no USB serial number): "
                      "ttyUSB numbers follow the order of enumeration and change between boots",
                      [f"/dev/serial/by-id: no link to {port.name}"] + (paths and
                                                                        [f"{paths[0]} -> {port.name}"] or []),
                      fix, port=port.device)


@check("names.shared", "identical adapters do not share one by-id name")
def names_shared(ctx: Context) -> Iterator[Finding]:
    groups: Dict[tuple, List[str]] = defaultdict(list)
    for p in ctx.all_ports():
        if p.vid_pid:
            groups[(p.vid_pid, p.serial)].append(p.name)
    checked = {p.name for p in ctx.ports()}
    for (vid_pid, serial), names in sorted(groups.items(), key=lambda kv: kv[1]):
        if len(names) < 2 or not checked & set(names):
            continue
        yield Finding("names.shared", "warning",
                      f"{', '.join(names)} are identical adapters ({vid_pid}, serial "
                      f"{serial or 'none'}): /dev/serial/by-id has one name for both, so it "
                      "points at whichever came last",
                      [f"/sys/class/tty/{n}: usb {vid_pid} serial {serial or '(none)'}" for n in names],
                      "use the /dev/serial/by-path names (one per USB socket), or give the "
                      "adapters distinct serial numbers (FTDI: ftdi_eeprom) or a udev rule on "
                      'KERNELS=="1-1.2" (`udevadm info -a /dev/ttyUSB0` shows the path)',
                      port=f"/dev/{names[0]}")
