"""The bridge as a service, through the entry point: Prometheus metrics, the systemd notify
protocol and watchdog, and the unit template."""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

from bridge_helpers import WAIT, need
from mosquitto import free_port

ROOT = Path(__file__).resolve().parents[3]
UNIT = ROOT / "examples" / "systemd" / "fap-bridge@.service"


def _start(tmp_path, broker_port, buses_toml, extra="", env=None):
    conf = tmp_path / "bridge.toml"
    conf.write_text(f'[bridge]\nhost = "svc"\nstate_dir = "st"\nstats_interval = 0.2\n{extra}'
                    f'[broker]\nurl = "mqtt://127.0.0.1:{broker_port}"\nreconnect_min = 0.05\n'
                    f'reconnect_max = 0.5\n{buses_toml}')
    return subprocess.Popen([sys.executable, "-m", "fap_py", "-v", "bridge", "--config", str(conf)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(tmp_path),
                            env=dict(os.environ, **(env or {})))


def _stop(proc):
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=WAIT + 10)
    assert proc.returncode == 0, err
    return err


def _fap_bus(path, name="line1", slaves="[1]"):
    return (f'[[bus]]\nname = "{name}"\nport = "{path}"\nprotocol = "fap"\nslaves = {slaves}\n'
            f'id_cycle = 0.1\n')


def test_prometheus_metrics(broker, observer_factory, tmp_path):
    from prometheus_client.parser import text_string_to_metric_families

    from fap_py.execasync import Slave as ExSlave
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    port = free_port()
    obs = observer_factory(broker.port)
    with VirtualBus(2) as fbus, VirtualBus(2) as ebus, Slave(fbus.paths[1], id=1) as s1, \
            ExSlave(ebus.paths[1], node=5, handler=lambda req: b"ok").start():
        buses = _fap_bus(fbus.paths[0]) + (
            f'[[bus]]\nname = "ex"\nport = "{ebus.paths[0]}"\nprotocol = "execasync"\nnodes = [5, 6]\n'
            f'poll_data = "01"\npoll_interval = 0.05\ntimeout = 0.05\nretries = 1\n')
        proc = _start(tmp_path, broker.port, buses, extra=f'[metrics]\nlisten = "127.0.0.1:{port}"\n')
        try:
            obs.wait_raw("fap/bridge/svc/status", b"online")
            for i in range(5):
                s1.send(bytes([i]), timeout=WAIT)
            obs.wait_for("fap/line1/1/rx", count=5)
            obs.wait_for("fap/ex/6/state", lambda d: d["state"] == "inactive")

            def scrape():
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=WAIT) as r:
                    assert r.headers["Content-Type"].startswith("text/plain")
                    return r.read().decode()

            def samples(text):
                out = {}
                for fam in text_string_to_metric_families(text):
                    for s in fam.samples:
                        out[(s.name, tuple(sorted(s.labels.items())))] = s.value
                return out

            deadline = time.monotonic() + WAIT
            while True:      # counters grow while the bridge runs: wait until each one moved
                text = scrape()
                got = samples(text)

                def v(name, **labels):
                    return got.get((name, tuple(sorted(labels.items()))), -1)

                ready = (v("fap_bridge_node_messages_total", bus="line1", node="1", direction="rx") >= 5
                         and v("fap_bridge_node_reply_seconds_count", bus="ex", node="5") > 0
                         and v("fap_bridge_node_timeouts_total", bus="ex", node="6") > 0)
                if ready or time.monotonic() > deadline:
                    break
                threading.Event().wait(0.05)
            assert ready, text
            assert v("fap_bridge_bus_up", bus="line1", protocol="fap") == 1
            assert v("fap_bridge_bus_frames_total", bus="line1", direction="rx") > 0
            assert v("fap_bridge_bus_frames_total", bus="ex", direction="tx") > 0
            assert v("fap_bridge_bus_crc_errors_total", bus="line1") == 0
            assert v("fap_bridge_bus_timeouts_total", bus="ex") > 0
            assert v("fap_bridge_bus_retries_total", bus="ex") > 0
            assert v("fap_bridge_bus_collisions_total", bus="line1") == 0
            assert v("fap_bridge_node_reply_seconds_bucket", bus="ex", node="5", le="+Inf") == \
                v("fap_bridge_node_reply_seconds_count", bus="ex", node="5")
            assert v("fap_bridge_node_active", bus="line1", node="1") == 1
            assert v("fap_bridge_node_active", bus="ex", node="6") == 0
            assert v("fap_bridge_mqtt_connected") == 1 and v("fap_bridge_outbox_rows") >= 0
            assert v("fap_bridge_mqtt_published_total") > 0 and v("fap_bridge_tx_refused_total") == 0
            assert ("fap_bridge_mqtt_refused_total" in text)      # declared even at zero
            promtool = shutil.which("promtool")
            need("promtool (Debian package prometheus)", promtool is not None)
            res = subprocess.run([promtool, "check", "metrics"], input=text, capture_output=True, text=True,
                                 timeout=60)
            assert res.returncode == 0 and not res.stdout.strip() and not res.stderr.strip(), res.stdout + res.stderr
        finally:
            _stop(proc)


def test_systemd_notify_ready_watchdog_stopping(broker, tmp_path):
    """A fake systemd: READY=1 after start, WATCHDOG=1 every WATCHDOG_USEC/2, STATUS=, STOPPING=1."""
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = str(tmp_path / "notify")
    sock.bind(path)
    sock.settimeout(WAIT)
    with VirtualBus(2) as bus, Slave(bus.paths[1], id=1), sock:
        proc = _start(tmp_path, broker.port, _fap_bus(bus.paths[0]),
                      env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"})
        got = []
        try:
            while True:
                got.append(sock.recv(4096).decode())
                pings = [m for m in got if m == "WATCHDOG=1"]
                if len(pings) >= 5 and any("broker connected" in m for m in got):
                    break
            assert got[0].startswith("READY=1\nSTATUS=")
            assert any(m.startswith("STATUS=broker connected; 1/1 buses running") for m in got), got
        finally:
            err = _stop(proc)
        while True:   # what was sent up to the exit
            try:
                sock.settimeout(0)
                got.append(sock.recv(4096).decode())
            except BlockingIOError:
                break
        assert any(m.startswith("STOPPING=1") for m in got), (got, err)


def test_unit_template_verifies(tmp_path):
    analyze = shutil.which("systemd-analyze")
    need("systemd-analyze (Debian package systemd)", analyze is not None)
    fap = shutil.which("fap", path=os.path.dirname(sys.executable)) or shutil.which("fap")
    assert fap, "the fap entry point is installed with the package"
    # verify checks that ExecStart exists: point it at this installation's fap
    (tmp_path / UNIT.name).write_text(UNIT.read_text().replace("/usr/bin/fap", fap))
    for unit in (UNIT.name, "fap-bridge@plant.service"):
        res = subprocess.run([analyze, "verify", f"./{unit}"], capture_output=True, text=True,
                             cwd=str(tmp_path), timeout=60)
        assert res.returncode == 0 and not res.stderr.strip(), res.stderr
    text = UNIT.read_text()
    for line in ("Type=notify", "WatchdogSec=", "DynamicUser=yes", "StateDirectory=fap-bridge/%i",
                 "ProtectSystem=strict", "DeviceAllow=char-ttyUSB rw", "--config /etc/fap/%i.toml"):
        assert line in text
