"""`--bundle FILE` (the evidence as a tar, secrets masked) and the end-to-end runs on
this machine's real devices: no PORT (every serial port found) and a pty."""
from __future__ import annotations

import json
import re
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest
from doctor_helpers import doctor

from fap_py.doctor._bundle import MASK, mask
from fap_py.vbus import VirtualBus

SECRETS = ("hunter2", "s3cr3t-tok", "pa55w0rd", "k3y-abc", "wifipsk99")


def test_bundle_masks_secrets(fap_main, tree, tmp_path):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    tree.write("/etc/systemd/system/fap-bridge.service",
               "[Service]\nUser=pi\nEnvironment=MQTT_PASSWORD=hunter2\n"
               "Environment=\"FAP_TOKEN=s3cr3t-tok\"\n"
               "ExecStart=/usr/bin/fap bridge --port /dev/ttyUSB0 --broker mqtt://bob:pa55w0rd@broker:1883 "
               "--api-key k3y-abc\n")
    tree.write("/boot/firmware/config.txt", "enable_uart=1\n# wpa psk: wifipsk99\n")
    tree.write("/proc/device-tree/model", "Raspberry Pi 4 Model B\0")
    out = tmp_path / "evidence.tar.gz"
    code, fs, err = doctor(fap_main, "/dev/ttyUSB0", "--root", str(tree.root), "--bundle", str(out))
    assert "wrote" in err and "secrets masked" in err
    with tarfile.open(out) as tar:
        names = tar.getnames()
        texts = {n: tar.extractfile(n).read().decode() for n in names}
    assert "fap-doctor/report.json" in names
    assert "fap-doctor/root/etc/systemd/system/fap-bridge.service" in names
    assert "fap-doctor/root/etc/group" in names and "fap-doctor/root/var/log/kern.log" in names
    unit = texts["fap-doctor/root/etc/systemd/system/fap-bridge.service"]
    assert f"MQTT_PASSWORD={MASK}" in unit and f"bob:{MASK}@broker" in unit
    for name, text in texts.items():
        for secret in SECRETS:
            assert secret not in text, (name, secret)
    report = [json.loads(line) for line in texts["fap-doctor/report.json"].splitlines()]
    assert {r["id"] for r in report} == {f["id"] for f in fs}


def test_mask_forms():
    assert mask('password = "x1"') == f'password = "{MASK}"'
    assert mask("token: abc") == f"token: {MASK}"
    assert mask('{"api_key":"zz", "n": 1}') == f'{{"api_key":"{MASK}", "n": 1}}'
    assert mask("mqtts://u:p@h") == f"mqtts://u:{MASK}@h"
    assert mask("fap x --password=abc --api-key k") == f"fap x --password={MASK} --api-key {MASK}"
    assert mask("baud = 9600") == "baud = 9600"


def test_bundle_unwritable(fap_main, tree, tmp_path):
    code, out, err = fap_main("doctor", "--root", str(tree.root), "--bundle",
                              str(tmp_path / "no" / "dir" / "x.tgz"))
    assert code == 3 and "--bundle" in err


def _fap() -> list:
    script = Path(sys.executable).with_name("fap")
    return [str(script)] if script.exists() else [sys.executable, "-m", "fap_py"]


@pytest.mark.timeout(60)
def test_end_to_end_this_machine():
    """No PORT: this machine and every serial port it has (the 16550 ttyS*)."""
    r = subprocess.run(_fap() + ["doctor", "--json"], capture_output=True, timeout=50,
                       stdin=subprocess.DEVNULL)
    assert r.returncode in (0, 4, 5), r.stderr
    rows = [json.loads(line) for line in r.stdout.decode().splitlines()]
    assert rows[-1]["event"] == "summary" and rows[-1]["exit"] == r.returncode
    assert all({"id", "severity", "evidence", "cause", "fix"} <= set(x) for x in rows[:-1])
    assert b"Traceback" not in r.stderr
    plain = subprocess.run(_fap() + ["doctor"], capture_output=True, timeout=50,
                           stdin=subprocess.DEVNULL)
    assert plain.returncode == r.returncode and b"Traceback" not in plain.stderr


@pytest.mark.timeout(60)
def test_end_to_end_on_a_pty():
    with VirtualBus(ports=2) as bus:
        r = subprocess.run(_fap() + ["doctor", bus.paths[0], "--json", "--baud", "9600"],
                           capture_output=True, timeout=50, stdin=subprocess.DEVNULL)
    assert r.returncode in (0, 4, 5) and b"Traceback" not in r.stderr, r.stderr
    rows = {x["id"]: x for x in (json.loads(line) for line in r.stdout.decode().splitlines())
            if x["event"] == "finding"}
    assert rows["port.exists"]["severity"] == "ok"
    assert rows["adapter.rs485"]["cause"].startswith("a pseudo-terminal")
    assert rows["port.termios"]["severity"] in ("ok", "info", "warning")


def test_rich_report_on_a_terminal(tree, monkeypatch, capsys):
    """On a terminal: the rich report, worst first."""
    from fap_py.cli import main

    tree.usb_tty("ttyUSB0", "ch341", "1a86:7523")
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True, raising=False)
    code = main(["doctor", "/dev/ttyUSB0", "--root", str(tree.root), "--user", "pi"])
    out = re.sub(r"\x1b\[[0-9;]*m", "", capsys.readouterr().out)
    assert code == 4
    assert out.index("WARNING") < out.index("OK")
    assert "fix:" in out and "exit 4" in out


@pytest.mark.timeout(60)
def test_end_to_end_listen_on_a_real_uart():
    """--listen on this machine's first 16550 (if it has one): every standard rate in
    turn, nothing sent, ends within its time."""
    from fap_py import sysfs_ports

    uarts = [p.device for p in sysfs_ports.list_ports() if p.name.startswith("ttyS")]
    if not uarts:
        pytest.skip("no ttyS port with a UART here")
    r = subprocess.run(_fap() + ["doctor", uarts[0], "--listen", "0.9", "--json"],
                       capture_output=True, timeout=50, stdin=subprocess.DEVNULL)
    assert r.returncode in (0, 4, 5) and b"Traceback" not in r.stderr, r.stderr
    rows = [json.loads(line) for line in r.stdout.decode().splitlines()]
    f = next(x for x in rows if x.get("id") == "listen.bus")
    assert f["severity"] in ("ok", "warning", "error")
    if f["severity"] != "error":        # opened: every rate tried
        assert "9 rates tried" in f["evidence"][0]
