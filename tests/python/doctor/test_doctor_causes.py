"""`fap doctor --root` on fixture trees reproducing each of the field's ten causes:
the first finding names the cause, with its evidence and the exact fix (issue 36)."""
from __future__ import annotations

import os

import pytest
from doctor_helpers import DIALOUT, PI_GID, PI_UID, doctor

ERROR, WARNING = 5, 4


def run(fap_main, tree, *args):
    return doctor(fap_main, *args, "--root", str(tree.root))


def first(findings):
    return findings[0]


def ids(findings, severity=None):
    return [f["id"] for f in findings if severity is None or f["severity"] == severity]


def test_healthy_tree_is_ok(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="usb-FTDI_A1-if00-port0",
                 latency=1)
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    assert code == 0, fs
    assert first(fs)["severity"] in ("ok", "info")
    assert {"perm.group", "port.holder", "adapter.latency", "adapter.rs485", "port.exists",
            "names.by_id", "brltty", "modemmanager", "getty.unit", "console.cmdline",
            "power.undervoltage"} <= set(ids(fs))
    rs = next(f for f in fs if f["id"] == "adapter.rs485")
    assert "by driver, rs485 no" in " ".join(rs["evidence"])     # fap ports' verdict for ftdi_sio


def test_user_not_in_group(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    tree.groups["dialout"] = (DIALOUT, [])
    tree.write_groups()
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "perm.group" and f["severity"] == "error"
    assert "pi is not in group dialout" in f["cause"]
    assert any("/etc/group:" in e and "dialout" in e for e in f["evidence"])
    assert "usermod -aG dialout pi" in f["fix"] and "log out and in again" in f["fix"]


def test_added_but_not_logged_in_again(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    tree.write("/proc/self/status", f"Name:\tbash\nUid:\t{PI_UID}\t{PI_UID}\t{PI_UID}\t{PI_UID}\n"
               f"Gid:\t{PI_GID}\t{PI_GID}\t{PI_GID}\t{PI_GID}\nGroups:\t{PI_GID} 27\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert f["id"] == "perm.relogin" and f["severity"] == "error", fs
    assert "has not logged in again" in f["cause"]
    assert f["evidence"][0].startswith("/proc/self/status: Groups:")
    assert "newgrp dialout" in f["fix"]
    # logged in again: the group is active
    tree.write("/proc/self/status", f"Uid:\t{PI_UID}\t{PI_UID}\t{PI_UID}\t{PI_UID}\nGroups:\t{PI_GID} {DIALOUT}\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    assert code == 0 and "ok" == next(f for f in fs if f["id"] == "perm.relogin")["severity"]


def test_container_gid_mismatch(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    del tree.groups["dialout"]
    tree.write_groups()
    tree.write("/proc/1/cgroup", "0::/system.slice/docker-0123abcd.scope\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "container.gid", fs
    assert f"group id {DIALOUT}" in f["cause"]
    assert any("docker" in e for e in f["evidence"])
    assert f"--group-add {DIALOUT}" in f["fix"]
    assert "perm.group" in ids(fs, "warning")
    tree.write("/.dockerenv", "")
    tree.groups["dialout"] = (DIALOUT, ["pi"])
    tree.write_groups()
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    assert code == 0 and "container.gid" in ids(fs, "ok")


def test_another_process_holds_the_port(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="usb-FTDI_A1-if00")
    tree.process(4242, "minicom", ["minicom", "-D", "/dev/ttyUSB0"], {0: "/dev/pts/1", 3: "/dev/ttyUSB0"})
    tree.process(4243, "python3", ["python3", "logger.py"],
                 {5: "/dev/serial/by-id/usb-FTDI_A1-if00"})   # through the by-id link
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "port.holder"
    assert "pid 4242 minicom" in f["cause"]
    assert "/proc/4242/fd/3 -> /dev/ttyUSB0" in f["evidence"]
    assert "kill 4242" in f["fix"]
    assert sum(1 for x in fs if x["id"] == "port.holder" and x["severity"] == "error") == 2


def test_lock_in_proc_locks(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    ino = os.stat(tree.p("/dev/ttyUSB0")).st_ino
    tree.write("/proc/77/comm", "mbusd\n")
    tree.write("/proc/locks", f"1: POSIX  ADVISORY  WRITE 12 00:1a:999 0 EOF\n"
               f"2: FLOCK  ADVISORY  WRITE 77 00:05:{ino} 0 EOF\n3: junk\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "port.lock" and "pid 77 mbusd" in f["cause"]
    assert f"/proc/locks:2: 2: FLOCK ADVISORY WRITE 77 00:05:{ino} 0 EOF" in f["evidence"]


def test_uucp_lock(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    tree.write("/run/lock/LCK..ttyUSB0", "      4242\n")
    tree.write("/proc/4242/comm", "cu\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "port.uucp_lock" and "pid 4242 cu" in f["cause"]
    # the holder is gone: a stale lock, the fix removes it
    (tree.p("/proc/4242/comm")).unlink()
    (tree.p("/proc/4242")).rmdir()
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"] == "port.uucp_lock" and "stale" in f["cause"]
    assert f["fix"] == "sudo rm /run/lock/LCK..ttyUSB0"
    tree.write("/run/lock/LCK..ttyUSB0", (4242).to_bytes(4, "little"))   # binary (old style)
    assert first(run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")[1])["id"] == "port.uucp_lock"


def test_brltty_claims_ch340(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ch341", "1a86:7523", by_id="usb-1a86_USB_Serial-if00-port0")
    tree.write("/lib/systemd/system/brltty-udev.service", "[Service]\nExecStart=/bin/brltty\n")
    tree.write("/usr/lib/udev/rules.d/85-brltty.rules", 'ENV{PRODUCT}=="1a86/7523/*", ENV{BRLTTY_BRAILLE_DRIVER}="bm"\n')
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"] == "brltty" and "CH340 (1a86:7523)" in f["cause"]
    tree.write("/var/log/kern.log",
               "Dec  1 kernel: usb 1-1: ch341-uart converter now attached to ttyUSB0\n"
               "Dec  1 kernel: usb 1-1: usbfs: interface 0 claimed by ch341 while 'brltty' sets config #1\n"
               "Dec  1 kernel: ch341-uart ttyUSB0: ch341-uart converter now disconnected from ttyUSB0\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "brltty"
    assert f["evidence"][0].startswith("/var/log/kern.log:2: ") and "'brltty'" in f["evidence"][0]
    assert "systemctl mask brltty.service brltty-udev.service" in f["fix"]


def test_modemmanager_probes_acm(fap_main, tree):
    tree.usb_tty("ttyACM0", "cdc_acm", "2341:0043", serial="85", by_id="usb-Arduino-if00")
    tree.enable("ModemManager.service")
    code, fs, _ = run(fap_main, tree, "/dev/ttyACM0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"] == "modemmanager"
    assert any("multi-user.target.wants/ModemManager.service" in e for e in f["evidence"])
    assert 'ATTRS{idVendor}=="2341", ATTRS{idProduct}=="0043", ENV{ID_MM_DEVICE_IGNORE}="1"' in f["fix"]
    tree.write("/etc/udev/rules.d/99-mm.rules",
               'ATTRS{idVendor}=="2341", ENV{ID_MM_DEVICE_IGNORE}="1"\n')
    code, fs, _ = run(fap_main, tree, "/dev/ttyACM0", "--user", "pi")
    assert code == 0 and "modemmanager" in ids(fs, "ok")
    tree.link("/etc/systemd/system/ModemManager.service", "/dev/null")   # masked
    assert "modemmanager" in ids(run(fap_main, tree, "/dev/ttyACM0", "--user", "pi")[1], "ok")


def test_getty_on_the_port(fap_main, tree):
    tree.uart("ttyS0")
    tree.write("/lib/systemd/system/serial-getty@.service", "[Service]\nExecStart=agetty\n")
    tree.link("/etc/systemd/system/getty.target.wants/serial-getty@ttyS0.service",
              "/lib/systemd/system/serial-getty@.service")
    code, fs, _ = run(fap_main, tree, "/dev/ttyS0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "getty.unit"
    assert f["evidence"] == ["/etc/systemd/system/getty.target.wants/serial-getty@ttyS0.service (enabled)"]
    assert "systemctl mask serial-getty@ttyS0.service" in f["fix"]


def test_kernel_console_on_the_port(fap_main, tree):
    tree.uart("ttyS0")
    tree.write("/proc/cmdline", "BOOT_IMAGE=/vmlinuz root=/dev/sda1 console=tty0 console=ttyS0,115200n8 quiet\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyS0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "console.cmdline"
    assert f["evidence"] == ["/proc/cmdline: console=ttyS0,115200n8"]
    assert "remove `console=ttyS0,115200n8`" in f["fix"]


def _pi(tree, model, config, serial0="ttyS0"):
    tree.write("/proc/device-tree/model", model + "\0")
    tree.write("/boot/firmware/config.txt", config)
    tree.uart("ttyS0", "bcm2835-aux-uart", 4)
    tree.uart("ttyAMA0", "uart-pl011", 32)
    tree.uart("ttyAMA10", "uart-pl011", 32)
    if serial0:
        tree.link("/dev/serial0", serial0)


def test_pi4_mini_uart_and_bluetooth(fap_main, tree):
    _pi(tree, "Raspberry Pi 4 Model B Rev 1.4",
        "[pi4]\narm_boost=1\n[all]\nenable_uart=1\n")
    code, fs, _ = run(fap_main, tree, "/dev/serial0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"] == "rpi.uart" and "mini UART (ttyS0)" in f["cause"]
    assert "dtoverlay=disable-bt" in f["fix"]
    # asking for ttyAMA0 without the overlay: that is Bluetooth's UART
    code, fs, _ = run(fap_main, tree, "/dev/ttyAMA0", "--user", "pi")
    assert code == ERROR and first(fs)["id"] == "rpi.uart" and "Bluetooth" in first(fs)["cause"]


def test_pi4_overlay_in_an_include(fap_main, tree):
    _pi(tree, "Raspberry Pi 4 Model B Rev 1.4",
        "[all]\ninclude uart.txt\n", serial0="ttyAMA0")
    tree.write("/boot/firmware/uart.txt", "enable_uart=1\ndtoverlay=disable-bt\n")
    code, fs, _ = run(fap_main, tree, "/dev/serial0", "--user", "pi")
    assert code == 0, fs
    uart = next(f for f in fs if f["id"] == "rpi.uart")
    assert uart["severity"] == "ok" and "/boot/firmware/uart.txt:2: dtoverlay=disable-bt" in uart["evidence"]


def test_pi4_uart_off_and_conflicting_overlays(fap_main, tree):
    _pi(tree, "Raspberry Pi 4 Model B Rev 1.4",
        "dtoverlay=disable-bt\ndtoverlay=miniuart-bt\n")
    code, fs, _ = run(fap_main, tree, "/dev/serial0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "rpi.enable_uart" and "enable_uart=1" in f["fix"]
    assert "rpi.overlays" in ids(fs, "warning")


def test_pi5_serial0_and_sections(fap_main, tree):
    _pi(tree, "Raspberry Pi 5 Model B Rev 1.0",
        "[pi4]\ndtoverlay=disable-bt\nenable_uart=0\n[pi5]\nenable_uart=1\n[all]\n", serial0="ttyAMA10")
    code, fs, _ = run(fap_main, tree, "/dev/serial0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"].startswith("rpi."), fs
    s0 = next(x for x in fs if x["id"] == "rpi.serial0")
    assert s0["severity"] == "warning" and "debug connector" in s0["cause"]
    assert "dtparam=uart0=on" in s0["fix"]
    ov = next(x for x in fs if x["id"] == "rpi.overlays" and x["severity"] == "warning")
    assert "[pi4]" in ov["cause"] and "config.txt:2" in ov["evidence"][0]
    assert "rpi.enable_uart" in ids(fs, "ok")     # [pi5] enable_uart=1 applies, [pi4]'s 0 not


def test_pi_without_serial0(fap_main, tree):
    _pi(tree, "Raspberry Pi 3 Model B Plus Rev 1.3", "[pi3]\nenable_uart=0\n[all]\n", serial0=None)
    code, fs, _ = run(fap_main, tree, "/dev/ttyS0", "--user", "pi")
    assert first(fs)["id"] == "rpi.enable_uart" and "enable_uart=0" in first(fs)["evidence"][1]
    assert "rpi.serial0" in ids(fs, "info")


def test_unstable_usb_name(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ch341", "1a86:7523")             # no serial number: no by-id
    tree.link("/dev/serial/by-path/platform-xhci-usb-0:1:1.0-port0", "../../ttyUSB0")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"] == "names.by_id" and "change between boots" in f["cause"]
    assert f["fix"].startswith("--port /dev/serial/by-path/platform-xhci-usb-0:1:1.0-port0")


def test_two_identical_adapters(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ch341", "1a86:7523", bus="1-1")
    tree.usb_tty("ttyUSB1", "ch341", "1a86:7523", bus="1-2")
    code, fs, _ = run(fap_main, tree, "--user", "pi")
    assert code == WARNING and first(fs)["id"].startswith("names.")
    shared = next(f for f in fs if f["id"] == "names.shared")
    assert "ttyUSB0, ttyUSB1 are identical adapters (1a86:7523" in shared["cause"]
    assert "by-path" in shared["fix"]
    rule = next(f for f in fs if f["id"] == "names.by_id")
    assert 'ATTRS{idVendor}=="1a86"' in rule["fix"]


def test_by_id_name_suggested(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="usb-FTDI_A1-if00")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = next(f for f in fs if f["id"] == "names.by_id")
    assert f["severity"] == "info" and f["fix"] == "--port /dev/serial/by-id/usb-FTDI_A1-if00"
    code, fs, _ = run(fap_main, tree, "/dev/serial/by-id/usb-FTDI_A1-if00", "--user", "pi")
    assert "names.by_id" in ids(fs, "ok")


def test_undervoltage(fap_main, tree, tmp_path):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    log = tmp_path / "dmesg.txt"
    log.write_text("[ 12.1] hwmon hwmon1: Undervoltage detected!\n[ 12.2] usb 1-1: USB disconnect, device number 3\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi", "--kernel-log", str(log))
    f = first(fs)
    assert code == ERROR and f["id"] == "power.undervoltage"
    assert f["evidence"][0] == f"{log}:1: [ 12.1] hwmon hwmon1: Undervoltage detected!"
    assert "1 USB disconnects in the log" in f["evidence"]
    os.unlink(tree.p("/var/log/kern.log"))
    tree.write("/dmesg", "[1.0] Under-voltage detected! (0x00050005)\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    assert first(fs)["evidence"][0].startswith("/dmesg:1:")
    os.unlink(tree.p("/dmesg"))
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    assert "power.undervoltage" in ids(fs, "info")


def test_ftdi_latency(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00", latency=16)
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == WARNING and f["id"] == "adapter.latency" and "16 ms" in f["cause"]
    assert f["evidence"] == ["/sys/class/tty/ttyUSB0/device/latency_timer: 16"]
    assert "echo 1 | sudo tee /sys/class/tty/ttyUSB0/device/latency_timer" in f["fix"]
    assert 'ATTR{latency_timer}="1"' in f["fix"]


def test_rs485_verdict_by_driver(fap_main, tree):
    tree.uart("ttyS0")
    tree.uart("ttyAMA0", "uart-pl011", 32)
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    code, fs, _ = run(fap_main, tree, "--user", "pi")
    rs = {f["port"]: f for f in fs if f["id"] == "adapter.rs485"}
    assert "cannot set it" in rs["/dev/ttyS0"]["cause"]
    assert "no kernel RS-485 ioctls" in rs["/dev/ttyUSB0"]["cause"]
    assert rs["/dev/ttyAMA0"]["cause"] == "RS-485 support unknown"


def test_unit_user_lacks_dialout(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="usb-FTDI_A1-if00")
    tree.write("/etc/passwd", tree.p("/etc/passwd").read_text() + "fapd:x:990:990::/:/usr/sbin/nologin\n")
    tree.write("/etc/systemd/system/fap-bridge.service",
               "[Unit]\nDescription=bridge\n[Service]\nUser=fapd\n"
               "ExecStart=/usr/bin/fap bridge --port /dev/serial/by-id/usb-FTDI_A1-if00\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "unit.user_group" and "runs as fapd" in f["cause"]
    assert "/etc/systemd/system/fap-bridge.service:4: User=fapd" in f["evidence"]
    assert "SupplementaryGroups=dialout" in f["fix"]
    # under --root the default user is the fap unit's
    code, out, _ = fap_main("doctor", "/dev/ttyUSB0", "--root", str(tree.root), "--json")
    assert '"user":"fapd"' in out.splitlines()[-1]
    tree.write("/etc/systemd/system/fap-bridge.service",
               "[Service]\nUser=fapd\nSupplementaryGroups=dialout\nExecStart=/usr/bin/fap bridge --port /dev/ttyUSB0\n")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB0", "--user", "pi")
    assert code == 0 and "unit.user_group" in ids(fs, "ok")


def test_missing_port(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    code, fs, _ = run(fap_main, tree, "/dev/ttyUSB3", "--user", "pi")
    f = first(fs)
    assert code == ERROR and f["id"] == "port.exists" and "ports here: /dev/ttyUSB0" in f["evidence"]


def test_no_ports_and_no_user(fap_main, tree):
    code, fs, _ = run(fap_main, tree)
    assert code == 0
    assert "port.exists" in ids(fs, "info") and "perm.group" in ids(fs, "info")


@pytest.mark.parametrize("argv,msg", [
    (["--root", "/nonexistent-doctor-root"], "not a directory"),
    (["--listen", "1"], "needs a PORT"),
])
def test_usage_errors(fap_main, argv, msg):
    code, _, err = fap_main("doctor", *argv)
    assert code == 2 and msg in err


def test_bare_port_name_is_a_dev_name(fap_main, tree):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x-if00")
    code, fs, _ = run(fap_main, tree, "ttyUSB0", "--user", "pi")
    assert next(f for f in fs if f["id"] == "port.exists")["severity"] == "ok"
