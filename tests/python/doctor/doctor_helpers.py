"""Fixture trees for the `fap doctor` tests: a fake machine under a temporary
root (sysfs of an FTDI, a CH340, a PL011, an 8250; /dev nodes; /etc; /proc;
systemd units; config.txt), and `fap doctor` run through the entry point."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Dict, List, Optional, Tuple

#: the group id the fixture's device nodes have (chown needs root; else ours)
DIALOUT = 20 if os.geteuid() == 0 else os.getgid()
PI_GID = 4001 if DIALOUT != 4001 else 4002
#: the fixture user: never the uid running the tests (an owner may open its node)
PI_UID = 31001 if os.getuid() != 31001 else 31002


class Tree:
    """A machine's files under ``root``; every path is the analysed machine's."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.write("/etc/passwd", "root:x:0:0:root:/root:/bin/bash\n"
                   f"pi:x:{PI_UID}:{PI_GID}::/home/pi:/bin/bash\n")
        self.groups: Dict[str, Tuple[int, List[str]]] = {
            "root": (0, []), "dialout": (DIALOUT, ["pi"]), "pi": (PI_GID, [])}
        if DIALOUT == 0:      # not root and in group 0: keep the names apart
            self.groups.pop("root")
        self.write_groups()
        self.write("/var/log/kern.log", "Dec  1 10:00:00 host kernel: Linux version 6.1.0\n")

    def p(self, path: str) -> Path:
        return self.root / path.lstrip("/")

    def write(self, path: str, text, mode: Optional[int] = None) -> Path:
        f = self.p(path)
        f.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            f.write_bytes(text)
        else:
            f.write_text(text)
        if mode is not None:
            f.chmod(mode)
        return f

    def link(self, path: str, target: str) -> None:
        f = self.p(path)
        f.parent.mkdir(parents=True, exist_ok=True)
        if f.is_symlink() or f.exists():
            f.unlink()
        os.symlink(target, f)

    def write_groups(self) -> None:
        self.write("/etc/group", "".join(f"{n}:x:{g}:{','.join(m)}\n"
                                         for n, (g, m) in self.groups.items()))

    def node(self, name: str, gid: int = DIALOUT, mode: int = 0o660) -> Path:
        f = self.write(f"/dev/{name}", "")
        f.chmod(mode)
        if os.geteuid() == 0:
            os.chown(f, 0, gid)
        return f

    def usb_tty(self, name: str, driver: str, vid_pid: str, serial: Optional[str] = None,
                by_id: Optional[str] = None, latency: Optional[int] = None,
                bus: str = "1-1") -> None:
        vid, pid = vid_pid.split(":")
        usb = f"/sys/devices/pci0000:00/usb1/{bus}"
        self.write(f"{usb}/idVendor", vid + "\n")
        self.write(f"{usb}/idProduct", pid + "\n")
        self.write(f"{usb}/product", f"adapter {driver}\n")
        if serial:
            self.write(f"{usb}/serial", serial + "\n")
        dev = f"{usb}/{bus}:1.0/{name}"
        self.p(dev).mkdir(parents=True, exist_ok=True)
        self._driver(dev, f"/sys/bus/usb-serial/drivers/{driver}")
        if latency is not None:
            self.write(f"{dev}/latency_timer", f"{latency}\n")
        self._class(name, dev)
        self.node(name)
        if by_id:
            self.link(f"/dev/serial/by-id/{by_id}", f"../../{name}")

    def uart(self, name: str, driver: str = "serial8250", uart_type: int = 4) -> None:
        dev = f"/sys/devices/platform/{driver}/tty/{name}"
        self.p(dev).mkdir(parents=True, exist_ok=True)
        self._driver(dev, f"/sys/bus/platform/drivers/{driver}")
        self._class(name, dev)
        self.write(f"/sys/class/tty/{name}/type", f"{uart_type}\n")
        self.node(name)

    def _driver(self, dev: str, drv: str) -> None:
        self.p(drv).mkdir(parents=True, exist_ok=True)
        os.symlink(os.path.relpath(self.p(drv), self.p(dev)), self.p(dev) / "driver")

    def _class(self, name: str, dev: str) -> None:
        cls = self.p(f"/sys/class/tty/{name}")
        cls.mkdir(parents=True, exist_ok=True)
        os.symlink(os.path.relpath(self.p(dev), cls), cls / "device")

    def enable(self, unit: str, target: str = "multi-user.target") -> None:
        self.write(f"/lib/systemd/system/{unit}", "[Service]\nExecStart=/bin/true\n")
        self.link(f"/etc/systemd/system/{target}.wants/{unit}", f"/lib/systemd/system/{unit}")

    def process(self, pid: int, comm: str, cmdline: List[str], fds: Dict[int, str]) -> None:
        self.write(f"/proc/{pid}/comm", comm + "\n")
        self.write(f"/proc/{pid}/cmdline", "\0".join(cmdline) + "\0")
        self.p(f"/proc/{pid}/fd").mkdir(parents=True, exist_ok=True)
        for fd, target in fds.items():
            self.link(f"/proc/{pid}/fd/{fd}", target)


def doctor(fap_main, *args: str) -> Tuple[int, List[dict], str]:
    """(exit code, finding objects worst first, stderr) of `fap doctor ARGS --json`."""
    code, out, err = fap_main("doctor", *args, "--json")
    rows = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert rows and rows[-1]["event"] == "summary", out
    return code, [r for r in rows if r["event"] == "finding"], err
