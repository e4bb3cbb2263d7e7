"""`fap serve` as a service: the systemd notify protocol (READY=1 once it listens,
WATCHDOG=1 pings, STOPPING=1), the unit template (systemd-analyze verify), the
configuration file and --check."""
from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from serve_helpers import WAIT_S, fap_cmd, start_daemon

from fap_py.execasync import Master

UNIT = Path(__file__).resolve().parents[3] / "examples" / "systemd" / "fap-serve@.service"


def test_systemd_notify_ready_watchdog_stopping(vbus, tmp_path):
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify")
    sock.bind(path)
    sock.settimeout(WAIT_S)
    with sock:
        d = start_daemon(str(tmp_path), vbus.master_port,
                         env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "100000"})
        got = []
        try:
            while sum(m == "WATCHDOG=1" for m in got) < 3:
                got.append(sock.recv(4096).decode())
            assert got[0].startswith("READY=1\nSTATUS=serving")
        finally:
            d.stop()
        sock.settimeout(0)
        while True:
            try:
                got.append(sock.recv(4096).decode())
            except BlockingIOError:
                break
        assert "STOPPING=1" in got


def test_unit_template_verifies(tmp_path):
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        if os.environ.get("CI"):
            pytest.fail("systemd-analyze (Debian package systemd) missing in CI")
        pytest.skip("systemd-analyze missing")
    fap = shutil.which("fap", path=os.path.dirname(sys.executable)) or shutil.which("fap")
    assert fap
    (tmp_path / UNIT.name).write_text(UNIT.read_text().replace("/usr/bin/fap", fap))
    for unit in (UNIT.name, "fap-serve@bus0.service"):
        res = subprocess.run([analyze, "verify", f"./{unit}"], capture_output=True, text=True,
                             cwd=str(tmp_path), timeout=60)
        assert res.returncode == 0 and not res.stderr.strip(), res.stderr
    text = UNIT.read_text()
    for line in ("Type=notify", "WatchdogSec=", "RuntimeDirectory=fap", "--check",
                 "--config /etc/fap/serve-%i.toml"):
        assert line in text


def test_config_file_and_check(vbus, tmp_path):
    cfg = tmp_path / "serve.toml"
    sock = tmp_path / "c.sock"
    cfg.write_text(f'protocol = "exec"\nport = "{vbus.master_port}"\nrs485 = "none"\n'
                   f'listen = ["unix:{sock}"]\nlock-dir = "{tmp_path}"\ntimeout = 0.05\n')
    r = subprocess.run(fap_cmd("serve", "--config", str(cfg), "--check", "--json"),
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["ok"] is True
    assert not list(tmp_path.glob("LCK..*"))                   # released again
    d = start_daemon(str(tmp_path), vbus.master_port)           # now the port is the daemon's
    try:
        r = subprocess.run(fap_cmd("serve", "--config", str(cfg), "--check"),
                           capture_output=True, text=True, timeout=30)
        assert r.returncode == 3 and f"pid {d.pid}" in r.stderr, r.stderr
        assert list(tmp_path.glob("LCK..*"))                    # the daemon's lock file
        with Master(d.url, timeout=0.1) as m:
            assert m.transact(5, b"x") == b"x"
    finally:
        d.stop()
    assert not list(tmp_path.glob("LCK..*"))
    bad = tmp_path / "bad.toml"
    bad.write_text('protocol = "exec"\nbogus = 1\n')
    r = subprocess.run(fap_cmd("serve", "--config", str(bad), "--check"), capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 2 and "bogus" in r.stderr


def test_prometheus_metrics(vbus, tmp_path):
    import urllib.error
    import urllib.request

    d = start_daemon(str(tmp_path), vbus.master_port, "--metrics", "tcp://127.0.0.1:0")
    try:
        with Master(d.url + "?name=scraped", timeout=0.5) as m:
            for i in range(3):
                m.transact(5, bytes([i]))
            text = urllib.request.urlopen(d.ready["metrics"], timeout=10).read().decode()
        assert "# TYPE fap_serve_transactions_total counter" in text
        assert f'fap_serve_transactions_total{{port="{vbus.master_port}",protocol="exec"}} 3' in text
        assert 'fap_serve_port_up{' in text and 'name="scraped"' in text
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(d.ready["metrics"].replace("/metrics", "/nope"), timeout=10)
        assert err.value.code == 404
    finally:
        d.stop()


def test_unix_socket_mode_owner_group(vbus, tmp_path):
    import grp
    import pwd
    import stat

    me, group = pwd.getpwuid(os.getuid()).pw_name, grp.getgrgid(os.getgid()).gr_name
    d = start_daemon(str(tmp_path), vbus.master_port, "--socket-mode", "600",
                     "--socket-owner", me, "--socket-group", group)
    try:
        st = os.stat(d.sock)
        assert stat.S_ISSOCK(st.st_mode) and stat.S_IMODE(st.st_mode) == 0o600
        assert (st.st_uid, st.st_gid) == (os.getuid(), os.getgid())
        (c,) = d.status()["clients"]               # the status call itself: SO_PEERCRED
        assert c["pid"] == os.getpid() and c["uid"] == os.getuid()
    finally:
        d.stop()
    assert not os.path.exists(d.sock)                           # removed at the end

    r = subprocess.run(fap_cmd("serve", "--protocol", "exec", "--port", vbus.master_port, "--rs485",
                               "none", "--listen", f"unix:{tmp_path}/x.sock", "--lock-dir",
                               str(tmp_path), "--socket-group", "no-such-group-fap", "--check"),
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "no-such-group-fap" in r.stderr
