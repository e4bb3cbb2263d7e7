"""``fap ports`` on a fake sysfs tree whose ports are real ptys of the
virtual bus: a 16550 (sysfs type 4, the port pyserial's ``hwid`` ``n/a``
hid) is listed, an empty 8250 slot (type 0) is not, the FTDI adapter shows
driver, VID:PID, serial, by-id name and latency timer, and a port another
program holds is reported "busy" without being opened."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import pytest

from fap_py import sysfs_ports
from fap_py.cli import main
from fap_py.commands import ports as ports_cmd
from fap_py.fap import RS485, RS485Mode
from fap_py.port import Port
from fap_py.vbus import VirtualBus


def _link(path: Path, target: Path | str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(target)


def _file(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n")


def fake_tree(root: Path, targets: dict[str, str]) -> tuple[Path, Path]:
    """sys/ and dev/ as the kernel lays them out for a q35 guest's ttyS0
    (16550A), ttyS1 (empty slot) and an FTDI ttyUSB0; dev/ entries are
    symlinks to the given ptys."""
    sys_, dev = root / "sys", root / "dev"
    for d in ("platform/drivers/serial8250", "pnp/drivers/serial", "serial-base/drivers/port",
              "serial-base/drivers/ctrl"):
        (sys_ / "bus" / d).mkdir(parents=True)
    # ttyS0 as Linux >= 6.5 has it: a serial-base port under a ctrl under
    # the PNP device whose driver is 8250's "serial"
    pnp = sys_ / "devices/pnp0/00:00"
    _link(pnp / "driver", sys_ / "bus/pnp/drivers/serial")
    _link(pnp / "subsystem", sys_ / "bus/pnp")
    for sub, drv in (("00:00:0", "ctrl"), ("00:00:0/00:00:0.0", "port")):
        _link(pnp / sub / "driver", sys_ / "bus/serial-base/drivers" / drv)
        _link(pnp / sub / "subsystem", sys_ / "bus/serial-base")
    _file(sys_ / "class/tty/ttyS0/type", "4")
    _link(sys_ / "class/tty/ttyS0/device", pnp / "00:00:0/00:00:0.0")
    # ttyS1 as 6.1 has it: the platform device of the legacy 8250 slots
    plat = sys_ / "devices/platform/serial8250"
    _link(plat / "driver", sys_ / "bus/platform/drivers/serial8250")
    _file(sys_ / "class/tty/ttyS1/type", "0")
    _link(sys_ / "class/tty/ttyS1/device", plat)
    usb = sys_ / "devices/pci0000:00/usb1/1-1"
    for f, v in (("idVendor", "0403"), ("idProduct", "6001"), ("serial", "A1B2C3"),
                 ("manufacturer", "FTDI"), ("product", "FT232R USB UART")):
        _file(usb / f, v)
    port = usb / "1-1:1.0/ttyUSB0"
    (sys_ / "bus/usb-serial/drivers/ftdi_sio").mkdir(parents=True)
    _link(port / "driver", sys_ / "bus/usb-serial/drivers/ftdi_sio")
    _file(port / "latency_timer", "16")
    _link(sys_ / "class/tty/ttyUSB0/device", port)
    (sys_ / "class/tty/tty0").mkdir(parents=True)   # virtual: no device
    for name, target in targets.items():
        _link(dev / name, target)
    _link(dev / "serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0", "../../ttyUSB0")
    return sys_, dev


@pytest.fixture
def tree(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[VirtualBus, Path]]:
    with VirtualBus(ports=2) as bus:
        sys_, dev = fake_tree(tmp_path, {"ttyS0": bus.paths[0], "ttyUSB0": bus.paths[1]})
        monkeypatch.setattr(ports_cmd, "SYSFS_ROOT", str(sys_))
        monkeypatch.setattr(ports_cmd, "DEV_ROOT", str(dev))
        yield bus, dev


def _rows(capsys: pytest.CaptureFixture, *args: str) -> dict[str, dict]:
    assert main(["ports", "--json", *args]) == 0
    return {o["device"]: o for o in map(json.loads, capsys.readouterr().out.splitlines())}


def test_sysfs_lists_16550_and_ftdi(tree: tuple[VirtualBus, Path]) -> None:
    _bus, dev = tree
    found = {p.name: p for p in sysfs_ports.list_ports(ports_cmd.SYSFS_ROOT, str(dev))}
    assert sorted(found) == ["ttyS0", "ttyUSB0"]
    s0, usb = found["ttyS0"], found["ttyUSB0"]
    assert (s0.uart_type, s0.driver, s0.description) == (4, "serial", "16550A")
    assert (usb.driver, usb.vid_pid, usb.serial, usb.latency_timer_ms) == \
        ("ftdi_sio", "0403:6001", "A1B2C3", 16)
    assert usb.by_id == str(dev / "serial/by-id/usb-FTDI_FT232R_USB_UART_A1B2C3-if00-port0")
    assert usb.description == "FTDI FT232R USB UART"
    everything = sysfs_ports.list_ports(ports_cmd.SYSFS_ROOT, str(dev), include_empty=True)
    assert [p.name for p in everything] == ["ttyS0", "ttyS1", "ttyUSB0"]
    assert sysfs_ports.list_ports(str(dev / "nowhere"), str(dev)) == []


def test_fap_ports_shows_the_16550(tree: tuple[VirtualBus, Path], capsys: pytest.CaptureFixture) -> None:
    _bus, dev = tree
    rows = _rows(capsys)
    assert sorted(rows) == [str(dev / "ttyS0"), str(dev / "ttyUSB0")]
    s0 = rows[str(dev / "ttyS0")]
    assert s0["description"] == "16550A" and s0["uart_type"] == 4 and s0["rs485"] == "no"
    usb = rows[str(dev / "ttyUSB0")]
    assert usb["vid_pid"] == "0403:6001" and usb["latency_timer_ms"] == 16
    assert main(["ports"]) == 0
    text = capsys.readouterr().out
    assert "16550A (driver serial)" in text
    assert "usb 0403:6001, serial A1B2C3, by-id " in text and "latency timer 16 ms" in text
    empty = _rows(capsys, "--all", "--no-probe")[str(dev / "ttyS1")]
    assert empty["uart_type"] == 0 and empty["driver"] == "serial8250"


def test_fap_ports_reports_a_held_port_busy(tree: tuple[VirtualBus, Path],
                                            capsys: pytest.CaptureFixture) -> None:
    bus, dev = tree
    with Port(bus.paths[1], 115200, RS485(mode=RS485Mode.NONE)):
        rows = _rows(capsys)
        assert rows[str(dev / "ttyUSB0")]["rs485"] == "busy"
        assert rows[str(dev / "ttyS0")]["rs485"] == "no"   # free: probed
        assert main(["ports"]) == 0
        assert "busy: held by another program (not opened)" in capsys.readouterr().out
    assert _rows(capsys)[str(dev / "ttyUSB0")]["rs485"] == "no"   # released: probed again


_HOSTILE_LIST = r"""
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))   # the old read grew to GBs
from fap_py import sysfs_ports
from fap_py.cli import main
from fap_py.commands import ports as ports_cmd
ports = sysfs_ports.list_ports(sys.argv[1], sys.argv[2])
print(json.dumps({p.name: [p.uart_type, p.product, p.latency_timer_ms] for p in ports}))
ports_cmd.SYSFS_ROOT, ports_cmd.DEV_ROOT = sys.argv[1], sys.argv[2]
sys.exit(main(["ports", "--json"]))
"""


def test_sysfs_fifo_and_dev_zero_are_not_read(tmp_path: Path) -> None:
    """Issue 32 item 18: a FIFO in a sysfs attribute's place blocked the open
    forever, a link to /dev/zero grew the process to GBs. Both are skipped
    (opened non-blocking, read only as regular files, at most a page), and
    the rest of the port is still listed."""
    import os
    import subprocess
    import sys
    import time

    sys_, dev = fake_tree(tmp_path, {"ttyS0": "/dev/null", "ttyUSB0": "/dev/null"})
    (sys_ / "class/tty/ttyS0/type").unlink()
    os.mkfifo(sys_ / "class/tty/ttyS0/type")           # nobody ever writes it
    usb = sys_ / "devices/pci0000:00/usb1/1-1"
    (usb / "product").unlink()
    (usb / "product").symlink_to("/dev/zero")
    latency = usb / "1-1:1.0/ttyUSB0/latency_timer"
    latency.unlink()
    os.mkfifo(latency)
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", _HOSTILE_LIST, str(sys_), str(dev)],
                       capture_output=True, text=True, timeout=20)
    took = time.monotonic() - t0
    assert r.returncode == 0, r.stderr
    assert took < 10, took
    found = json.loads(r.stdout.splitlines()[0])
    assert found["ttyS0"] == [None, None, None]          # the FIFO: no type, listed anyway
    assert found["ttyUSB0"] == [None, "FTDI", None]      # /dev/zero and the FIFO: not read
    rows = [json.loads(line) for line in r.stdout.splitlines()[1:]]
    assert {row["device"] for row in rows} == {str(dev / "ttyS0"), str(dev / "ttyUSB0")}
