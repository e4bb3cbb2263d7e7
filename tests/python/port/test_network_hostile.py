"""Hostile network servers on 127.0.0.1 against ``fap_py.port.Port`` and the
CLI (issue 32 items 10-12, issue 33 item 3): every open, Ctrl-C and close
ends within a bound generous for a loaded 2-core machine, whatever the
server does.

* RFC 2217 servers that flood Telnet (NOP, DO/DONT, a subnegotiation that
  never ends): before, the open looped in ``telnet_recv`` for good.
* A server that stops reading: a write waited 2 s past ``close()``.
* A raw TCP server behind ``rfc2217://``: before, the open succeeded
  silently and the negotiation went onto the bus as data.
* A DNS server that never answers (a child in its own mount and network
  namespace with ``/etc/resolv.conf`` bind-mounted to 127.0.0.1:53; root
  only): before, the open took 10 s at ``connect_ms=500``.
"""
from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import Optional

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_network_cli import COMMANDS, EXIT_PORT, fap, one_error_line

from fap_py.errors import ClosedError, FapError, PortError
from fap_py.port import Port

#: the bound for an open, a close, a Ctrl-C (the issue's target is 0.5 s)
BOUND = 1.5

IAC, SB, SE, NOP, DO, DONT, WILL = 255, 250, 240, 241, 253, 254, 251
GOOD_HELLO = bytes([IAC, DO, 0, IAC, WILL, 0, IAC, DO, 44])
#: the client's last SET-CONTROL at open (RTS on; the baud query after it is the fence)
LAST_SETTING = bytes([IAC, SB, 44, 5, 11, IAC, SE])


#: a server's answers to the line settings (cmd + 100, value) and to the three SET-CONTROLs
LINE_ANSWERS = [(101, (115200).to_bytes(4, "big")), (102, b"\x08"), (103, b"\x01"), (104, b"\x01")]
CONTROL_ANSWERS = [(105, b"\x01"), (105, b"\x08"), (105, b"\x0b")]


def _answers(pairs: list) -> bytes:
    return b"".join(bytes([IAC, SB, 44, cmd]) + v + bytes([IAC, SE]) for cmd, v in pairs)


def _hello_until_settings(c: socket.socket) -> bool:
    """Negotiate as a real server, then read until the client's last SET-CONTROL has come
    (False: the client left first)."""
    c.sendall(GOOD_HELLO)
    seen = b""
    while LAST_SETTING not in seen:
        chunk = c.recv(1)
        if not chunk:
            return False
        seen = seen[-16:] + chunk
    return True


class Hostile:
    """A TCP server on 127.0.0.1 that misbehaves in one way, per connection:
    ``nop``/``dodont``/``sb`` flood from the start, ``noread`` negotiates
    then never reads again, ``silent`` (a raw TCP port on a quiet bus) takes
    the bytes and says nothing, ``close`` closes at once, ``lineonly``
    answers the line settings and nothing after them."""

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self.lst = socket.create_server(("127.0.0.1", 0))
        self.port = self.lst.getsockname()[1]
        self.accepted = threading.Event()
        self.connections = 0
        self.settled = threading.Event()
        self._stop = threading.Event()
        self._conns: list = []
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def url(self, scheme: str = "rfc2217", query: str = "") -> str:
        return f"{scheme}://127.0.0.1:{self.port}{query}"

    def _run(self) -> None:
        self.lst.settimeout(0.05)
        while not self._stop.is_set():
            try:
                c, _ = self.lst.accept()
            except OSError:
                continue
            self._conns.append(c)
            self.connections += 1
            if self.kind != "good_once" or self.connections > 1:
                self.accepted.set()
            threading.Thread(target=self._serve, args=(c,), daemon=True).start()

    def _serve(self, c: socket.socket) -> None:
        try:
            if self.kind == "close":
                c.close()
                return
            if self.kind == "good_once" and self.connections == 1:
                # a real server's open, then it drops the line; later ones: silent
                if not _hello_until_settings(c):
                    return
                c.sendall(_answers(LINE_ANSWERS + CONTROL_ANSWERS))
                while b"!" not in c.recv(4096):   # the client's word that it is open
                    pass
                c.close()
                return
            if self.kind == "lineonly":
                # answers the line settings, never SET-CONTROL nor the baud query
                if not _hello_until_settings(c):
                    return
                c.sendall(_answers(LINE_ANSWERS))
            if self.kind in ("silent", "good_once", "lineonly"):
                while not self._stop.is_set() and c.recv(4096):
                    pass
                return
            if self.kind == "noread":
                if not _hello_until_settings(c):
                    return
                self.settled.set()
                self._stop.wait()       # never reads again
                return
            # big chunks: the kernel copies them faster than the client parses,
            # so its receive queue never runs dry (as a C server's would not)
            flood = {"nop": bytes([IAC, NOP]) * (1 << 17),
                     "dodont": bytes([IAC, DO, 0, IAC, DONT, 0]) * (1 << 16),
                     "sb": b"x" * (1 << 18)}[self.kind]
            c.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 21)
            if self.kind == "sb":
                c.sendall(bytes([IAC, SB, 44]))
            c.settimeout(0.05)
            while not self._stop.is_set():
                try:
                    c.send(flood)
                except socket.timeout:
                    continue
        except OSError:
            pass

    def close(self) -> None:
        self._stop.set()
        self._th.join()
        self.lst.close()
        for c in self._conns:
            try:
                c.close()
            except OSError:
                pass

    def __enter__(self) -> "Hostile":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def test_a_server_silent_after_the_line_settings_is_waited_for_then_named_slow(
        caplog: pytest.LogCaptureFixture) -> None:
    """No SET-CONTROL answer and no answer to the baud query sent after them
    (the fence): the open waits option_ms for them, goes on, and the warning
    says how to wait longer."""
    with Hostile("lineonly") as srv, caplog.at_level(logging.WARNING, logger="fap_py.port"):
        t0 = time.monotonic()
        with Port(srv.url(query="?option_ms=200"), 115200):
            took = time.monotonic() - t0
    assert 0.2 <= took < BOUND
    msgs = [r.getMessage() for r in caplog.records if "SET-CONTROL" in r.getMessage()]
    assert len(msgs) == 1 and "within 200 ms" in msgs[0], msgs
    assert "wait longer with ?option_ms=N" in msgs[0], msgs


@pytest.mark.parametrize("kind", ["nop", "dodont", "sb"])
def test_telnet_flood_open_is_bounded(kind: str) -> None:
    with Hostile(kind) as srv:
        t0 = time.monotonic()
        try:
            with Port(srv.url(query="?option_ms=200&connect_ms=500"), 115200) as p:
                p.read(64, timeout=0.1)
        except FapError:
            pass                          # a documented refusal is fine too
        assert time.monotonic() - t0 < BOUND


_CTRL_C_OPEN = r"""
import sys
from fap_py.port import Port
try:
    Port(sys.argv[1], 115200)
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
"""


def _interrupt_child(code: str, url: str, ready: threading.Event) -> float:
    """Run code in a child, SIGINT it once ready is set: seconds to its exit."""
    child = subprocess.Popen([sys.executable, "-c", code, url], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(300):                # a child that failed at once says why, now
            if ready.wait(0.1) or child.poll() is not None:
                break
        if not ready.is_set():
            out, err = child.communicate(timeout=10) if child.poll() is not None else ("", "")
            raise AssertionError(f"the child never connected: {child.returncode} {out} {err}")
        t0 = time.monotonic()
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=10)
        took = time.monotonic() - t0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 130, (child.returncode, out, err)
    assert "interrupted" in out
    return took


@pytest.mark.parametrize("kind", ["nop", "sb", "silent"])
def test_ctrl_c_ends_a_network_open(kind: str) -> None:
    """The open waits up to option_ms = 10 minutes; Ctrl-C ends it at once."""
    with Hostile(kind) as srv:
        took = _interrupt_child(_CTRL_C_OPEN, srv.url(query="?option_ms=600000"), srv.accepted)
    assert took < BOUND, took


_CTRL_C_REOPEN = r"""
import sys, time
from fap_py.errors import PortGoneError
from fap_py.port import Port
p = Port(sys.argv[1], 115200)
p.write(b"!")                        # open: the server drops the line now
try:
    while True:
        p.read(64, timeout=1)
except PortGoneError:
    pass
try:
    p.reopen()
except KeyboardInterrupt:
    t0 = time.monotonic()
    p.close()
    print("interrupted", round(time.monotonic() - t0, 3), flush=True)
    sys.exit(130)
"""


def test_ctrl_c_ends_a_network_reopen() -> None:
    """The server dropped the line and now never negotiates: Port.reopen() waits
    up to option_ms = 10 minutes; Ctrl-C ends it, close() after it is quick."""
    with Hostile("good_once") as srv:
        took = _interrupt_child(_CTRL_C_REOPEN, srv.url(query="?option_ms=600000"), srv.accepted)
    assert took < BOUND, took


def test_close_ends_a_write_to_a_server_that_does_not_read() -> None:
    with Hostile("noread") as srv:
        p = Port(srv.url(query="?option_ms=50"), 115200)
        assert srv.settled.wait(10)
        result: list = []

        def writer() -> None:
            try:
                for _ in range(64):
                    p.write(b"\xff" * (1 << 20))
                result.append("done")
            except FapError as exc:
                result.append(exc)

        th = threading.Thread(target=writer)
        th.start()
        th.join(0.3)                       # it is stuck: the server reads nothing
        assert th.is_alive()
        t0 = time.monotonic()
        p.close()
        th.join(5)
        took = time.monotonic() - t0
    assert not th.is_alive()
    assert took < 1.0, took               # before: the 2 s send wait, past the close
    assert isinstance(result[0], ClosedError), result


def test_rfc2217_on_a_raw_tcp_server_is_refused() -> None:
    with Hostile("silent") as srv:
        t0 = time.monotonic()
        with pytest.raises(PortError) as ei:
            Port(srv.url(query="?option_ms=100"), 115200)
        assert time.monotonic() - t0 < BOUND
    text = str(ei.value)
    assert "not an RFC 2217 server" in text and f"tcp://127.0.0.1:{srv.port}" in text, text


def test_server_that_closes_says_so() -> None:
    with Hostile("close") as srv:
        with pytest.raises(PortError) as ei:
            Port(srv.url(query="?option_ms=100"), 115200)
    assert "connection closed by the server" in str(ei.value)


@pytest.mark.parametrize("cmd", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_cli_refuses_rfc2217_on_a_raw_server(cmd: tuple) -> None:
    """Every protocol's command, not only G485's: exit 3, one line naming the
    URL and tcp://."""
    with Hostile("silent") as srv:
        url = srv.url(query="?option_ms=100")
        code, _, err = fap(*cmd[:2], "--port", url, *cmd[2:], timeout=30)
    assert code == EXIT_PORT, err
    one_error_line(err, f"127.0.0.1:{srv.port}", "tcp://")


# ---- a DNS server that never answers ----------------------------------------

_DNS_CHILD = r"""
import os, signal, socket, sys, threading, time
from fap_py.errors import PortError
from fap_py.port import Port
u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
u.bind(("127.0.0.1", 53))           # takes every query, answers none
name = "fap-dns-test.example"     # in /etc/hosts until the Master part
other = "fap-unknown.example"     # never there: every lookup goes to the DNS
t0 = time.monotonic()
try:
    Port(f"tcp://{other}:4001?connect_ms=500", 115200)
    print("opened?!")
except PortError as exc:
    print("refused", round(time.monotonic() - t0, 3), exc, flush=True)
# Ctrl-C during a lookup with connect_ms = 60 s
threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT)).start()
t0 = time.monotonic()
try:
    Port(f"rfc2217://{other}:4001?connect_ms=60000", 115200)
except KeyboardInterrupt:
    print("interrupted", round(time.monotonic() - t0 - 0.2, 3), flush=True)
# Master.close() while its engine reopens and waits for the lookup: the name
# is in /etc/hosts for the open, gone (a lookup the DNS never answers) for
# the reopen after the server dropped the connection
from fap_py.fap import Master
srv = socket.create_server(("127.0.0.1", 0))
m = Master(f"tcp://{name}:{srv.getsockname()[1]}?connect_ms=60000", 115200, slaves=[3])
c, _ = srv.accept()
subprocess_ok = os.system(f"mount --bind {sys.argv[1]} /etc/hosts") == 0
c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\0\0\0\0\0\0\0")
c.close()                            # a reset: the engine reopens
u.settimeout(20)
while b"fap-dns-test" not in u.recvfrom(512)[0]:
    pass                             # (the abandoned lookup above still asks, too)
# the reopen's lookup reached the DNS server: the engine waits there now
t0 = time.monotonic()
m.close()
print("closed", round(time.monotonic() - t0, 3), subprocess_ok, flush=True)
"""


def _dns_sandbox() -> Optional[str]:
    """Why the fake DNS cannot be set up here, or None."""
    if os.geteuid() != 0:
        return "needs root (a mount namespace)"
    if not shutil.which("unshare") or not shutil.which("ip"):
        return "needs unshare(1) and ip(8)"
    return None


def test_dns_that_never_answers(tmp_path) -> None:
    why = _dns_sandbox()
    if why:
        pytest.skip(why)
    conf = tmp_path / "resolv.conf"
    conf.write_text("nameserver 127.0.0.1\n")
    hosts, no_name = tmp_path / "hosts", tmp_path / "hosts-without"
    hosts.write_text("127.0.0.1 localhost fap-dns-test.example\n")
    no_name.write_text("127.0.0.1 localhost\n")
    script = tmp_path / "child.py"
    script.write_text(_DNS_CHILD)
    cmd = (f"ip link set lo up && mount --bind {conf} /etc/resolv.conf && "
           f"mount --bind {hosts} /etc/hosts && exec {sys.executable} {script} {no_name}")
    r = subprocess.run(["unshare", "--mount", "--net", "sh", "-c", cmd], capture_output=True,
                       text=True, timeout=60)
    if r.returncode != 0 and "unshare" in r.stderr:
        pytest.skip(f"no namespaces here: {r.stderr.strip()}")
    print(r.stdout)
    lines = r.stdout.splitlines()
    assert len(lines) == 3, (r.stdout, r.stderr)
    word, took, *rest = lines[0].split(" ", 2)
    assert word == "refused" and float(took) < BOUND, lines[0]   # before: 10.0 s
    assert "not resolved" in lines[0], lines[0]
    word, took = lines[1].split()
    assert word == "interrupted" and float(took) < BOUND, lines[1]   # before: 9.4 s
    word, took, mounted = lines[2].split()
    assert mounted == "True", lines[2]
    assert word == "closed" and float(took) < BOUND, lines[2]   # before: 8.7 s


# ---- the bridge: one hostile bus must not keep the others offline -------------

@pytest.mark.parametrize("kind", ["nop", "dodont", "sb"])
def test_bridge_runs_beside_a_flooding_rfc2217_bus(tmp_path, kind: str) -> None:
    """Issue 32 item 10: one bus on a server that floods Telnet kept the whole
    bridge offline (the healthy bus forwarded 0 messages in 8 s, SIGTERM took
    11.4 s). Now its open ends within option_ms, the healthy bus forwards at
    once and the bridge stops within the bound."""
    bridge_dir = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bridge")
    sys.path.insert(0, bridge_dir)
    try:
        from bridge_helpers import WAIT, Observer, bridge_config, need
        from mosquitto import MOSQUITTO, Mosquitto
    finally:
        sys.path.remove(bridge_dir)
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        mqtt = None
    need("paho-mqtt", mqtt is not None)
    need("mosquitto", MOSQUITTO is not None)
    from fap_py.bridge import Bridge
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    with Mosquitto(str(tmp_path / "broker")) as broker, VirtualBus(2) as bus, \
            Slave(bus.paths[1], id=1) as s1, Hostile(kind) as srv:
        buses = [{"name": "line1", "port": bus.paths[0], "protocol": "fap", "slaves": [1],
                  "id_cycle": 0.1},
                 {"name": "line2", "port": srv.url(query="?option_ms=200&connect_ms=500"),
                  "protocol": "fap", "slaves": [3], "id_cycle": 0.1, "reopen_interval": 0.05}]
        obs = Observer(mqtt, broker.port)
        try:
            t0 = time.monotonic()
            bridge = Bridge(bridge_config(broker.port, str(tmp_path / "state"), buses))
            bridge.start()
            try:
                assert time.monotonic() - t0 < 2 * BOUND    # both opens: bounded
                assert bridge.wait_connected(WAIT)
                s1.send(b"\x01")                              # line1 runs meanwhile
                obs.wait_for("fap/line1/1/rx", lambda d: d["data"] == "01")
            finally:
                t0 = time.monotonic()
                bridge.stop()
                took = time.monotonic() - t0
            assert took < BOUND, took                           # before: 11.4 s
        finally:
            obs.close()
