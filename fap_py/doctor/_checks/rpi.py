"""The Raspberry Pi UART mapping: which UART the GPIO 14/15 pins carry
(``rpi.uart``), ``enable_uart`` (``rpi.enable_uart``), overlays that conflict or
sit in a section this model ignores (``rpi.overlays``) and where ``serial0``
points (``rpi.serial0``). config.txt is read with its ``[filter]`` sections and
``include`` lines."""
from __future__ import annotations

import posixpath
import re
from dataclasses import dataclass
from typing import Iterator, List, Optional, Set

from .._context import Context
from .._finding import Finding
from .._registry import check

CONFIGS = ("/boot/firmware/config.txt", "/boot/config.txt")
MODEL_FILES = ("/proc/device-tree/model", "/sys/firmware/devicetree/base/model")
INCLUDE_DEPTH = 5
#: overlays that give the PL011 back to the GPIO pins
PL011_OVERLAYS = {"disable-bt", "pi3-disable-bt", "miniuart-bt", "pi3-miniuart-bt"}


@dataclass(frozen=True)
class Setting:
    key: str
    value: str
    where: str      # "file:line"
    applies: bool
    section: str


def model(ctx: Context) -> Optional[str]:
    for p in MODEL_FILES:
        text = ctx.read(p, 4096)
        if text and text.strip():
            return text.strip()
    return None


def _filters(m: str) -> Set[str]:
    """The config.txt model filters that apply to model string ``m``."""
    out = {"all"}
    if "Pi 5" in m or "Compute Module 5" in m or "Pi 500" in m:
        out |= {"pi5", "cm5"}
    elif "Pi 4" in m or "Compute Module 4" in m or "Pi 400" in m:
        out |= {"pi4", "pi400" if "400" in m else "pi4", "cm4" if "Compute" in m else "pi4"}
    elif "Pi 3" in m or "Compute Module 3" in m:
        out |= {"pi3", "pi3+" if "Plus" in m else "pi3"}
    elif "Zero 2" in m:
        out |= {"pi02", "pi0"}
    elif "Zero" in m:
        out |= {"pi0", "pi0w" if "W" in m else "pi0"}
    return out


_MODEL_FILTERS = re.compile(r"^(pi\d+\w*|cm\d+\w*|pi0\w*|pi02|pi400|pi500|all|none)$")


def settings(ctx: Context, m: str) -> tuple:
    """(settings in file order, the config file read or None)."""
    applies_to = _filters(m)
    out: List[Setting] = []
    seen: Set[str] = set()

    def read(path: str, depth: int, applies: bool, section: str) -> tuple:
        if depth > INCLUDE_DEPTH or path in seen:
            return applies, section
        seen.add(path)
        for n, raw in enumerate(ctx.lines(path), 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            if line.startswith("[") and line.endswith("]"):
                name = line[1:-1].strip().lower()
                section = name
                if _MODEL_FILTERS.match(name):
                    applies = name in applies_to
                continue      # other filters (gpio, serial numbers ...): taken as applying
            if line.startswith("include "):
                inc = posixpath.join(posixpath.dirname(path), line.split(None, 1)[1].strip())
                applies, section = read(inc, depth + 1, applies, section)
                continue
            key, sep, value = line.partition("=")
            if sep:
                out.append(Setting(key.strip(), value.strip(), f"{path}:{n}", applies, section))
        return applies, section

    for cfg in CONFIGS:
        if ctx.read(cfg) is not None:
            read(cfg, 0, True, "all")
            return out, cfg
    return out, None


def _overlays(sets: List[Setting], applying: bool = True) -> List[Setting]:
    return [s for s in sets if s.key == "dtoverlay" and s.applies == applying]


def _overlay_name(s: Setting) -> str:
    return s.value.split(",", 1)[0].strip()


def _has_bt(m: str) -> bool:
    return any(k in m for k in ("Pi 3", "Pi 4", "Pi 400", "Zero W", "Zero 2", "Compute Module 4"))


def _pi(ctx: Context) -> Optional[str]:
    m = model(ctx)
    return m if m and "Raspberry Pi" in m else None


@check("rpi.uart", "the GPIO 14/15 pins carry a stable UART (Raspberry Pi)")
def rpi_uart(ctx: Context) -> Iterator[Finding]:
    m = _pi(ctx)
    if m is None or not _has_bt(m):
        return
    sets, cfg = settings(ctx, m)
    pl011 = [s for s in _overlays(sets) if _overlay_name(s) in PL011_OVERLAYS]
    asked = {p.name for p in ctx.ports()}
    ev = [f"/proc/device-tree/model: {m}"]
    if pl011:
        yield Finding("rpi.uart", "ok", f"the PL011 is on GPIO 14/15 ({_overlay_name(pl011[-1])})",
                      ev + [f"{pl011[-1].where}: dtoverlay={pl011[-1].value}"])
        return
    fix = (f"add under [all] in {cfg or CONFIGS[0]}:\ndtoverlay=disable-bt\n"
           "then `sudo systemctl disable hciuart` and reboot (GPIO 14/15 get the PL011, "
           "ttyAMA0 = serial0)")
    if "ttyAMA0" in asked:
        yield Finding("rpi.uart", "error",
                      "ttyAMA0 (the PL011) is wired to the Bluetooth chip on this Pi, not to "
                      "GPIO 14/15", ev + [f"{cfg or 'config.txt'}: no dtoverlay=disable-bt or miniuart-bt"],
                      fix, port="/dev/ttyAMA0")
    else:
        yield Finding("rpi.uart", "warning",
                      "GPIO 14/15 carry the mini UART (ttyS0): its baud follows the VPU core "
                      "clock, and Bluetooth has the PL011",
                      ev + [f"{cfg or 'config.txt'}: no dtoverlay=disable-bt or miniuart-bt"], fix)


@check("rpi.enable_uart", "the GPIO UART is enabled (Raspberry Pi)")
def rpi_enable_uart(ctx: Context) -> Iterator[Finding]:
    m = _pi(ctx)
    if m is None:
        return
    sets, cfg = settings(ctx, m)
    en = [s for s in sets if s.key == "enable_uart" and s.applies]
    ev = [f"/proc/device-tree/model: {m}"]
    if en and en[-1].value.strip() == "1":
        yield Finding("rpi.enable_uart", "ok", "enable_uart=1", ev + [f"{en[-1].where}: enable_uart=1"])
        return
    ignored = [s for s in sets if s.key == "enable_uart" and not s.applies]
    what = (f"{en[-1].where}: enable_uart={en[-1].value}" if en else
            f"{ignored[-1].where}: enable_uart={ignored[-1].value} in [{ignored[-1].section}], "
            "which this model ignores" if ignored else f"{cfg or 'config.txt'}: no enable_uart line")
    yield Finding("rpi.enable_uart", "warning" if "Pi 5" in m else "error",
                  "the UART on GPIO 14/15 is off (enable_uart is not 1)" +
                  ("" if "Pi 5" in m else "; on the mini UART it also pins the core clock"),
                  ev + [what], f"add under [all] in {cfg or CONFIGS[0]}:\nenable_uart=1\nthen reboot")


@check("rpi.overlays", "the UART overlays do not conflict (Raspberry Pi)")
def rpi_overlays(ctx: Context) -> Iterator[Finding]:
    m = _pi(ctx)
    if m is None:
        return
    sets, cfg = settings(ctx, m)
    on = [s for s in _overlays(sets) if _overlay_name(s) in PL011_OVERLAYS]
    kinds = {_overlay_name(s).replace("pi3-", "") for s in on}
    if len(kinds) > 1:
        yield Finding("rpi.overlays", "warning",
                      "disable-bt and miniuart-bt both apply: only one may own the PL011",
                      [f"{s.where}: dtoverlay={s.value}" for s in on],
                      "keep one: dtoverlay=disable-bt (Bluetooth off) or dtoverlay=miniuart-bt "
                      "(Bluetooth on the mini UART, then core_freq=250 on a Pi 3)")
    for s in _overlays(sets, applying=False):
        if _overlay_name(s) in PL011_OVERLAYS or "uart" in s.value:
            yield Finding("rpi.overlays", "warning",
                          f"dtoverlay={s.value} is in a [{s.section}] section, which this "
                          f"{m} ignores", [f"{s.where}: dtoverlay={s.value} (section [{s.section}])",
                                           f"/proc/device-tree/model: {m}"],
                          f"move the line under [all] (or this model's section) in {cfg}")
    if len(kinds) <= 1:
        yield Finding("rpi.overlays", "ok", "no conflicting UART overlays")


@check("rpi.serial0", "serial0 names the GPIO UART (Raspberry Pi)")
def rpi_serial0(ctx: Context) -> Iterator[Finding]:
    m = _pi(ctx)
    if m is None:
        return
    target = ctx.readlink("/dev/serial0")
    ev = [f"/proc/device-tree/model: {m}"]
    if target is None:
        yield Finding("rpi.serial0", "info", "no /dev/serial0 link (the UART is off, or udev has "
                      "no Raspberry Pi rules)", ev + ["/dev/serial0: absent"],
                      "enable_uart=1 in config.txt; use the tty name (ttyAMA0 / ttyS0)")
        return
    name = posixpath.basename(target)
    ev.append(f"/dev/serial0 -> {target}")
    if "Pi 5" in m and name != "ttyAMA0":
        yield Finding("rpi.serial0", "warning",
                      f"on a Pi 5 serial0 is {name}, the 3-pin debug connector, not GPIO 14/15",
                      ev, "use /dev/ttyAMA0 and add under [pi5] or [all] in config.txt:\n"
                      "dtparam=uart0=on", port="/dev/serial0")
    elif name == "ttyS0" and _has_bt(m):
        yield Finding("rpi.serial0", "info", "serial0 is the mini UART (ttyS0): see rpi.uart",
                      ev, port="/dev/serial0")
    else:
        yield Finding("rpi.serial0", "ok", f"serial0 is {name}", ev, port="/dev/serial0")
