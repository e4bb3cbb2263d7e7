"""``--port tcp://...`` and ``--port rfc2217://...`` at the ``fap`` command line.

Bad URLs, refused connections, refused parameters and an RS-485 mode a URL
cannot have: one ``fap: error:`` line and the documented exit code (2 usage,
3 port). Then the FAP, exec async, mikroC and G485 commands and ``fap
monitor`` against nodes behind ser2net.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from typing import List, Tuple

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from net_helpers import WAIT, Rfc2217Server, Ser2net, free_port

from fap_py import Slave as FapSlave
from fap_py.vbus import VirtualBus

EXIT_USAGE, EXIT_PORT = 2, 3
NONE = ("--rs485", "none")


def fap(*args: str, timeout: float = 60) -> Tuple[int, str, str]:
    """The installed command as a process (-I: not the source tree)."""
    env = dict(os.environ, COLUMNS="100")
    p = subprocess.run([sys.executable, "-I", "-m", "fap_py", *args], capture_output=True,
                       text=True, timeout=timeout, env=env)
    return p.returncode, p.stdout, p.stderr


def one_error_line(err: str, *words: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fap: error: "), err
    for w in words:
        assert w in lines[0], err


#: one command per protocol, port left out
COMMANDS = [
    ("fap", "master", "--slaves", "3", "--to", "3", "6869"),
    ("exec", "master", "--node", "5", "0102"),
    ("mikroc", "master", "--address", "5", "01"),
    ("g485", "read", "--address", "1", "--register", "1"),
    ("monitor",),
]


@pytest.mark.parametrize("url", ["tcp://", "tcp://host", "tcp://host:99999", "foo://host:1",
                                 "tcp://host:1?bogus=1"])
@pytest.mark.parametrize("cmd", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_bad_url_is_a_usage_error(cmd: Tuple[str, ...], url: str) -> None:
    code, _, err = fap(*cmd[:2], "--port", url, *cmd[2:])
    assert code == EXIT_USAGE
    # G485 hands a scheme libfap does not know to pyserial, which says so itself
    one_error_line(err, url, "URL")


@pytest.mark.parametrize("cmd", COMMANDS, ids=[c[0] for c in COMMANDS])
def test_refused_connection_is_a_port_error(cmd: Tuple[str, ...]) -> None:
    url = f"tcp://127.0.0.1:{free_port()}"
    code, _, err = fap(*cmd[:2], "--port", url, *cmd[2:])
    assert code == EXIT_PORT
    one_error_line(err, url, "refused")


@pytest.mark.parametrize("mode", ["kernel", "soft"])
def test_rs485_direction_on_a_url_is_a_usage_error(mode: str) -> None:
    url = f"tcp://127.0.0.1:{free_port()}"
    code, _, err = fap("exec", "master", "--port", url, "--rs485", mode, "--node", "5", "01")
    assert code == EXIT_USAGE
    one_error_line(err, "server's")


def test_refused_baud_is_a_port_error() -> None:
    with VirtualBus(ports=2) as bus, Rfc2217Server(bus.paths[0], refuse_baud=57600) as srv:
        code, _, err = fap("exec", "master", "--port", srv.url, "--baud", "57600",
                           "--node", "5", "01")
    assert code == EXIT_PORT
    one_error_line(err, "refused a line setting")


def _json(text: str) -> List[dict]:
    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


@pytest.mark.parametrize("which", [0, 1], ids=["raw", "rfc2217"])
def test_fap_master_command_through_ser2net(served: Tuple[VirtualBus, Ser2net],
                                            which: int) -> None:
    bus, s = served
    with FapSlave(bus.paths[2], id=3) as slave:
        slave.send(b"temp=21.5")
        code, out, err = fap("fap", "master", "--port", s.urls[which], "--slaves", "3",
                             "--id-cycle", "0.05", "--text", "--json", "--interval", "0.5",
                             "hello")
        assert code == 0, err
        objs = _json(out)
        assert {"event": "tx", "to": 3, "data": b"hello".hex()} in objs
        assert {"event": "rx", "from": 3, "data": b"temp=21.5".hex()} in objs
        assert slave.recv(timeout=WAIT).data == b"hello"


def test_exec_master_and_slave_commands_through_ser2net(served: Tuple[VirtualBus, Ser2net]) -> None:
    _, s = served
    slave = subprocess.Popen([sys.executable, "-I", "-m", "fap_py", "exec", "slave", "--port",
                              s.urls[1], *NONE, "--node", "5", "--json"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert slave.stdout is not None
        assert json.loads(slave.stdout.readline())["event"] == "ready"
        code, out, err = fap("exec", "master", "--port", s.urls[0], *NONE, "--node", "5",
                             "--json", "--count", "3", "--interval", "0", "--timeout", "1",
                             "ff0d0a")
        assert code == 0, err
        replies = [o for o in _json(out) if o["event"] == "reply"]
        assert [o["data"] for o in replies] == ["ff0d0a"] * 3
    finally:
        slave.terminate()
        slave.communicate(timeout=WAIT)


def test_monitor_reads_a_url(served: Tuple[VirtualBus, Ser2net]) -> None:
    """fap monitor on the RFC 2217 URL decodes what is written on the bus
    (ser2net has the device open once the RFC 2217 settings are answered,
    which is before the monitor says it listens)."""
    from fap_py.execasync import encode
    from fap_py.port import Port

    bus, s = served
    frame = encode(5, b"\xff\x0d\x00", 1)
    mon = subprocess.Popen([sys.executable, "-I", "-m", "fap_py", "monitor", "--port", s.urls[1],
                            "--protocol", "exec", "--json", "--idle", "1"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert mon.stderr is not None
        line = mon.stderr.readline()
        while "fap_py.port WARNING" in line or line.startswith("fap: warning: "):   # a quirk
            line = mon.stderr.readline()
        assert "listening on" in line
        with Port(bus.paths[2], 115200) as dev:
            dev.write(frame)
        out, err = mon.communicate(timeout=60)
    finally:
        if mon.poll() is None:
            mon.kill()
            mon.communicate()
    assert mon.returncode == 0, err
    frames = [o for o in _json(out) if o.get("node") == 5]
    assert frames and frames[0]["data"] == "ff0d00", out
