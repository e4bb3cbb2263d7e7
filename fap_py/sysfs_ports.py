"""The machine's serial ports, read from sysfs (``/sys/class/tty``).

pyserial's ``list_ports`` gives ``hwid`` ``n/a`` for a real 16550 on
recent kernels, so a filter on it hides the port; sysfs says directly
whether a UART is there (serial_core's ``type``: 0 is PORT_UNKNOWN, an
empty legacy 8250 slot). For each port with a hardware device behind it:
the driver, USB VID:PID, serial number and product, the
``/dev/serial/by-id`` name and the FTDI ``latency_timer``. Only reads
files; never opens a tty. The roots are parameters (tests pass a fake
tree).
"""
from __future__ import annotations

import logging
import os
import stat
from dataclasses import dataclass
from typing import Dict, List, Optional

from ._validate import check_bool, check_path

__all__ = ["SerialPort", "list_ports", "UART_TYPES"]

log = logging.getLogger(__name__)

#: serial_core's PORT_* numbers (include/uapi/linux/serial_core.h) for the
#: UARTs this project meets; others are shown as "type N".
UART_TYPES: Dict[int, str] = {1: "8250", 2: "16450", 3: "16550", 4: "16550A", 5: "Cirrus",
                              6: "16650", 7: "16650V2", 8: "16750", 32: "AMBA (PL010/PL011)"}


@dataclass(frozen=True)
class SerialPort:
    """One serial port as sysfs describes it."""

    name: str                       #: ttyS0, ttyUSB0 ...
    device: str                     #: /dev path
    driver: Optional[str]           #: kernel driver of the device (serial8250, ftdi_sio ...)
    uart_type: Optional[int]        #: serial_core PORT_* (None: not a serial_core port)
    vid_pid: Optional[str] = None   #: USB "0403:6001"
    serial: Optional[str] = None    #: USB serial number
    product: Optional[str] = None   #: USB manufacturer and product
    by_id: Optional[str] = None     #: /dev/serial/by-id link that names it
    latency_timer_ms: Optional[int] = None   #: FTDI's receive latency timer

    @property
    def description(self) -> str:
        """One phrase: the USB product, else the UART type, else the driver."""
        if self.product:
            return self.product
        if self.uart_type:
            return UART_TYPES.get(self.uart_type, f"type {self.uart_type}")
        return self.driver or "serial port"


#: the most read of one sysfs attribute (a PAGE_SIZE page is all sysfs gives)
READ_MAX = 4096


def _read(path: str) -> Optional[str]:
    """A sysfs attribute's text, or None. Bounded: opened non-blocking and read
    only when it is a regular file (a FIFO would block the open, ``/dev/zero``
    never ends), at most :data:`READ_MAX` bytes."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        return os.read(fd, READ_MAX).decode("utf-8", errors="replace").strip()
    except OSError:
        return None
    finally:
        os.close(fd)


def _read_int(path: str) -> Optional[int]:
    text = _read(path)
    try:
        return int(text, 0) if text is not None else None
    except ValueError:
        return None


def _usb_device_dir(dev_dir: str) -> Optional[str]:
    """The USB device directory (with idVendor) above a tty's device."""
    d = os.path.realpath(dev_dir)
    for _ in range(4):
        if os.path.exists(os.path.join(d, "idVendor")):
            return d
        d = os.path.dirname(d)
    return None


def _driver(dev_dir: str) -> Optional[str]:
    """The driver of the hardware: since Linux 6.5 a UART's tty device is a
    serial-base "port" under a "ctrl" under the real device (8250 "serial",
    "serial8250"); look above those."""
    d = os.path.realpath(dev_dir)
    while os.path.basename(os.path.realpath(os.path.join(d, "subsystem"))) == "serial-base":
        d = os.path.dirname(d)
    drv = os.path.join(d, "driver")
    return os.path.basename(os.path.realpath(drv)) if os.path.exists(drv) else None


def _by_id_names(dev_root: str) -> Dict[str, str]:
    """realpath of the target -> /dev/serial/by-id link."""
    out: Dict[str, str] = {}
    by_id = os.path.join(dev_root, "serial", "by-id")
    try:
        names = sorted(os.listdir(by_id))
    except OSError:
        return out
    for n in names:
        link = os.path.join(by_id, n)
        target = os.path.normpath(os.path.join(by_id, os.readlink(link))) \
            if os.path.islink(link) else link
        out.setdefault(os.path.basename(target), link)
    return out


def list_ports(sysfs: str = "/sys", dev_root: str = "/dev",
               include_empty: bool = False) -> List[SerialPort]:
    """Every tty with a hardware device behind it, sorted by name.
    ``include_empty``: also serial_core slots whose type is 0 (no UART)."""
    sysfs = check_path(sysfs, "sysfs")
    dev_root = check_path(dev_root, "dev_root")
    check_bool(include_empty, "include_empty")
    cls = os.path.join(sysfs, "class", "tty")
    try:
        names = sorted(os.listdir(cls))
    except OSError as exc:
        log.debug("no %s: %s", cls, exc)
        return []
    by_id = _by_id_names(dev_root)
    ports = []
    for name in names:
        base = os.path.join(cls, name)
        dev_dir = os.path.join(base, "device")
        if not os.path.exists(dev_dir):
            continue   # virtual (tty0, console, ptmx ...)
        uart = _read_int(os.path.join(base, "type"))
        if uart == 0 and not include_empty:
            continue   # a legacy 8250 slot without a UART behind it
        driver = _driver(dev_dir)
        usb = _usb_device_dir(dev_dir)
        vid_pid = serial = product = None
        if usb:
            vid, pid = _read(os.path.join(usb, "idVendor")), _read(os.path.join(usb, "idProduct"))
            vid_pid = f"{vid}:{pid}" if vid and pid else None
            serial = _read(os.path.join(usb, "serial"))
            words = [_read(os.path.join(usb, f)) for f in ("manufacturer", "product")]
            product = " ".join(w for w in words if w) or None
        ports.append(SerialPort(
            name=name, device=os.path.join(dev_root, name), driver=driver, uart_type=uart,
            vid_pid=vid_pid, serial=serial, product=product, by_id=by_id.get(name),
            latency_timer_ms=_read_int(os.path.join(dev_dir, "latency_timer"))))
    return ports
