"""The doctor room's pieces one by one: the context on this machine (systemctl,
dmesg, the invoking user), RS-485 verdicts and termios of a live port, the Pi
model filters, lock formats, bounds."""
from __future__ import annotations

import os
import termios

import pytest
from doctor_helpers import doctor

from fap_py.doctor import _context as context
from fap_py.doctor import _listen as listen
from fap_py.doctor import _registry as registry
from fap_py.doctor._checks import holders, permissions, rpi
from fap_py.doctor._context import Context
from fap_py.vbus import VirtualBus


def run(ctx, check_id):
    return registry.run(ctx, only=[check_id])


def test_systemctl_when_systemd_runs(monkeypatch):
    ctx = Context(root="/", port="/dev/null")
    monkeypatch.setattr(ctx, "systemd_live", lambda: True)
    answers = {"enabled\n": True, "disabled\n": False, "not-found\n": None}
    for out, want in answers.items():
        monkeypatch.setattr(context, "_run", lambda cmd, out=out: out)
        assert ctx.unit_enabled("ModemManager.service")[0] is want
        assert ctx.unit_enabled("x")[1].startswith("systemctl is-enabled x: ")
    monkeypatch.setattr(context, "_run", lambda cmd: None)     # systemctl failed: the files
    assert ctx.unit_enabled("no-such-unit-here.service")[0] is None


def test_run_helper():
    assert context._run(["/nonexistent/tool"]) is None
    assert context._run(["false"]) is None
    assert context._run(["echo", "hi"]) == "hi\n"


def test_dmesg_on_this_machine(monkeypatch):
    ctx = Context(root="/")
    monkeypatch.setattr(ctx, "read", lambda *a, **k: None)
    monkeypatch.setattr(context, "_run", lambda cmd: "[1.0] Under-voltage detected!\n")
    assert ctx.kernel_log() == ["[1.0] Under-voltage detected!"] and ctx.kernel_log_source == "dmesg"
    f = run(ctx, "power.undervoltage")[0]
    assert f.severity == "error" and f.evidence[0] == "dmesg:1: [1.0] Under-voltage detected!"


def test_kernel_log_file_missing(tmp_path):
    ctx = Context(root=str(tmp_path), kernel_log=str(tmp_path / "none"))
    assert ctx.kernel_log() == [] and ctx.kernel_log_source is None


def test_invoking_user(monkeypatch):
    monkeypatch.setenv("SUDO_USER", "alice")
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    assert Context(root="/").user == "alice"
    monkeypatch.delenv("SUDO_USER")
    import getpass

    def no_user():
        raise KeyError("uid not in passwd")
    monkeypatch.setattr(getpass, "getuser", no_user)
    assert Context(root="/").user is None


def test_malformed_passwd_and_group(tree):
    tree.write("/etc/group", "# comment\nbad\nx:x:notanumber:\n:x:5:\ndialout:x:20:pi, bob ,\n")
    tree.write("/etc/passwd", "# c\nshort:x\nu:x:a:b::\npi:x:1000:1000::/:/bin/sh\n")
    ctx = Context(root=str(tree.root))
    assert [(g.name, g.members) for g in ctx.groups()] == [("dialout", ("pi", "bob"))]
    assert [u.name for u in ctx.users()] == ["pi"]
    assert ctx.group_by_name("dialout").gid == 20 and ctx.group_by_name("none") is None


def test_listing_and_links_bounded(tree, monkeypatch):
    for i in range(5):
        tree.write(f"/etc/many/{i}", "")
    monkeypatch.setattr(context, "LIST_MAX", 2)
    ctx = Context(root=str(tree.root))
    assert len(ctx.listdir("/etc/many")) == 2
    tree.link("/a", "b")
    tree.link("/b", "a")
    assert ctx.readlink("/a/x") is None and ctx.host("/a") is None and ctx.stat("/a") is None
    assert not ctx.isdir("/a") and ctx.isdir("/etc")
    assert ctx.listdir("/a") == []


def test_hostile_sysfs_is_no_ports(tree, monkeypatch):
    from fap_py import sysfs_ports

    def boom(*a, **k):
        raise RuntimeError("bad sysfs")
    monkeypatch.setattr(sysfs_ports, "list_ports", boom)
    assert Context(root=str(tree.root)).all_ports() == []


@pytest.mark.parametrize("verdict,severity,text", [
    ({"rs485": "yes"}, "ok", "use --rs485 kernel"),
    ({"rs485": "busy"}, "warning", "busy"),
    ({"rs485": "unknown", "error": "Input/output error"}, "info", "unknown"),
    ({"rs485": "read-only"}, "info", "cannot set it"),
    ({"rs485": "no"}, "info", "no kernel RS-485 ioctls"),
])
def test_rs485_probe_verdicts(tree, verdict, severity, text):
    tree.uart("ttyS1")
    ctx = Context(root=str(tree.root), port="/dev/ttyS1", probe=True)
    ctx.__dict__["_probes"] = {"/dev/ttyS1": verdict}
    f = run(ctx, "adapter.rs485")[0]
    assert f.severity == severity and text in f.cause, f
    assert run(ctx, "port.termios") == []          # never read under --root


def _set(path, fn):
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        a = termios.tcgetattr(fd)
        fn(a)
        termios.tcsetattr(fd, termios.TCSANOW, a)
    finally:
        os.close(fd)


def test_termios_of_a_live_port(fap_main):
    with VirtualBus(ports=2) as bus:
        path = bus.paths[0]
        hold = os.open(path, os.O_RDWR | os.O_NOCTTY)     # keeps the settings
        try:
            def raw19200(a):
                a[0] &= ~(termios.IXON | termios.IXOFF)
                a[2] &= ~(termios.CRTSCTS | termios.CSIZE | termios.PARENB)
                a[2] |= termios.CS8
                a[4] = a[5] = termios.B19200
            _set(path, raw19200)
            code, fs, _ = doctor(fap_main, path, "--baud", "9600")
            f = next(x for x in fs if x["id"] == "port.termios")
            assert f["severity"] == "warning" and "19200 baud, not the 9600" in f["cause"]
            assert f["fix"].startswith(f"stty -F {os.path.realpath(path)} 9600")
            code, fs, _ = doctor(fap_main, path, "--baud", "19200")
            assert next(x for x in fs if x["id"] == "port.termios")["severity"] == "ok"

            def crtscts(a):
                a[2] |= termios.CRTSCTS | termios.PARENB | termios.PARODD | termios.CSTOPB
            _set(path, crtscts)
            code, fs, _ = doctor(fap_main, path)
            f = next(x for x in fs if x["id"] == "port.termios")
            assert f["severity"] == "warning" and "crtscts" in f["cause"] and "8N2" in f["evidence"][0]   # a pty keeps no parity

            def ixon(a):
                a[2] &= ~(termios.CRTSCTS | termios.PARODD)
                a[0] |= termios.IXON
            _set(path, ixon)
            code, fs, _ = doctor(fap_main, path)
            f = next(x for x in fs if x["id"] == "port.termios")
            assert f["severity"] == "info" and "XON/XOFF" in f["cause"] and "8N2 ixon" in f["evidence"][0]
        finally:
            os.close(hold)


def test_read_termios_of_no_tty(tmp_path):
    from fap_py.doctor._checks.adapter import read_termios
    assert read_termios(str(tmp_path / "none")) is None
    f = tmp_path / "file"
    f.write_text("")
    assert read_termios(str(f)) is None


@pytest.mark.parametrize("model,filters", [
    ("Raspberry Pi 3 Model B Plus Rev 1.3", {"all", "pi3", "pi3+"}),
    ("Raspberry Pi Zero 2 W Rev 1.0", {"all", "pi02", "pi0"}),
    ("Raspberry Pi Zero W Rev 1.1", {"all", "pi0", "pi0w"}),
    ("Raspberry Pi Compute Module 4 Rev 1.0", {"all", "pi4", "cm4"}),
    ("Raspberry Pi 5 Model B Rev 1.0", {"all", "pi5", "cm5"}),
    ("Raspberry Pi Model B Rev 2", {"all"}),
])
def test_pi_model_filters(model, filters):
    assert rpi._filters(model) == filters


def test_pi_without_config(tree):
    tree.write("/proc/device-tree/model", "Raspberry Pi 4 Model B\0")
    ctx = Context(root=str(tree.root))
    assert rpi.settings(ctx, rpi.model(ctx)) == ([], None)
    f = run(ctx, "rpi.enable_uart")[0]
    assert f.severity == "error" and "no enable_uart line" in f.evidence[1]
    assert run(Context(root=str(tree.root / "nothing")), "rpi.uart") == []


def test_lock_pid_forms():
    assert holders._lock_pid("  42\n") == 42
    assert holders._lock_pid("abc") is None
    assert holders._lock_pid("\x00\x00\x00\x00") is None


def test_fd_scan_bounded(tree, monkeypatch):
    tree.usb_tty("ttyUSB0", "ftdi_sio", "0403:6001", serial="A1", by_id="x")
    tree.process(5, "a", ["a"], dict.fromkeys(range(5), "/dev/null"))
    tree.process(6, "b", ["b"], {0: "/dev/ttyUSB0"})
    monkeypatch.setattr(holders, "FD_SCAN_MAX", 3)
    ctx = Context(root=str(tree.root), port="/dev/ttyUSB0")
    assert holders.holders(ctx, ctx.ports()[0]) == []


def test_process_groups_on_this_machine(monkeypatch, tree):
    ctx = Context(root="/")
    assert permissions._process_groups(ctx, os.getuid() + 1) is None
    gids, ev = permissions._process_groups(ctx, os.getuid())
    assert os.getgid() in gids and ev.startswith("this process")
    tree.write("/proc/self/status", "Uid:\t7\nGroups:\n")
    assert permissions._process_groups(Context(root=str(tree.root)), 1000) is None


def test_may_open_rules():
    assert permissions._may_open(5, [], (5, 0, 0o600, ""))
    assert permissions._may_open(5, [], (0, 0, 0o666, ""))
    assert not permissions._may_open(5, [1], (0, 2, 0o660, ""))


def test_brltty_installed_without_adapter(fap_main, tree):
    tree.uart("ttyS0")
    tree.write("/lib/udev/rules.d/85-brltty.rules", "# rules\n")
    code, fs, _ = doctor(fap_main, "/dev/ttyS0", "--root", str(tree.root), "--user", "pi")
    assert next(f for f in fs if f["id"] == "brltty")["severity"] == "info"


def test_console_in_cmdline_txt(fap_main, tree):
    tree.uart("ttyAMA0", "uart-pl011", 32)
    tree.link("/dev/serial0", "ttyAMA0")
    tree.write("/boot/firmware/cmdline.txt", "console=serial0,115200 console=tty1 root=PARTUUID=1\n")
    code, fs, _ = doctor(fap_main, "/dev/ttyAMA0", "--root", str(tree.root), "--user", "pi")
    f = fs[0]
    assert f["id"] == "console.cmdline" and f["evidence"] == ["/boot/firmware/cmdline.txt: console=serial0,115200"]
    assert "from /boot/firmware/cmdline.txt" in f["fix"]


def test_listen_bounds(fap_main):
    code, _, err = fap_main("doctor", "/dev/null", "--listen", "0")
    assert code == 2 and "--listen must be in" in err


def test_wire_times_unknown_baud():
    cap = [(1, b"a"), (5, b"b")]
    assert listen.wire_times(cap, 0) is cap


def test_holder_scan_says_when_it_is_blind(monkeypatch, tmp_path):
    node = tmp_path / "ttyX0"
    node.write_text("")
    monkeypatch.setattr(os, "geteuid", lambda: 4242)
    ctx = Context(root="/", port=str(node))
    f = run(ctx, "port.holder")[0]
    assert f.severity == "ok" and "not readable" in f.evidence[0]
