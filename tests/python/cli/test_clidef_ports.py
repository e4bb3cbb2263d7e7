"""Issue 33 item 5 and the hostile `--check ""`: `fap ports --check` on a
tcp:// URL (a real echoing TCP server on 127.0.0.1) times mode none without
`--rs485` and never names a choice the option refuses; on a pty the default
soft falls back to none and says so; `--device URL` is listed as a network
port, not probed as a file; an empty `--check` or `--device` is a usage
error."""
from __future__ import annotations

import json
import socket
import threading
from typing import Iterator

import pytest

from fap_py.vbus import VirtualBus

from .conftest import run_proc


@pytest.fixture
def echo_server() -> Iterator[str]:
    """A raw TCP server on 127.0.0.1 that sends every byte back (a serial
    server whose line echoes, as a 2-wire transceiver does)."""
    srv = socket.create_server(("127.0.0.1", 0))
    srv.settimeout(30)
    stop = threading.Event()

    def serve() -> None:
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            with conn:
                while True:
                    try:
                        data = conn.recv(4096)
                    except OSError:
                        break
                    if not data:
                        break
                    conn.sendall(data)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    stop.set()
    try:
        srv.shutdown(socket.SHUT_RDWR)   # wakes the blocked accept() (close alone does not)
    except OSError:
        pass
    srv.close()
    t.join(timeout=10)
    assert not t.is_alive()


def test_check_on_a_tcp_url_needs_no_rs485(echo_server: str) -> None:
    res = run_proc("ports", "--check", echo_server, "--baud", "9600", "--rounds", "2", "--json")
    assert res.code in (0, 1), res          # timed (warnings are the adapter's, exit 1)
    (row,) = [json.loads(line) for line in res.lines()]
    assert row["event"] == "check" and row["mode"] == "none" and row["echoed"] == 2, row
    assert row["notes"] == []
    assert "auto" not in res.err
    soft = run_proc("ports", "--check", echo_server, "--rs485", "soft")
    assert soft.code == 2, soft
    assert soft.err == (f"fap: error: {echo_server}: --rs485 soft: a network port has no RTS "
                        "line here (the server switches the direction); use --rs485 none, the "
                        "default for a URL\n")
    assert "auto" not in soft.err


def test_check_on_a_pty_says_it_fell_back() -> None:
    with VirtualBus(ports=2, echo=True) as bus:
        res = run_proc("ports", "--check", bus.paths[0], "--rounds", "1")
        assert res.code in (0, 1), res
        assert "  note: the port has no RTS line (a pty, say): timed with --rs485 none, not " \
            "the default soft" in res.out
        js = run_proc("ports", "--check", bus.paths[0], "--rounds", "1", "--json")
        (row,) = [json.loads(line) for line in js.lines()]
        assert row["mode"] == "none" and len(row["notes"]) == 1, row
        explicit = run_proc("ports", "--check", bus.paths[0], "--rounds", "1", "--rs485", "soft")
        assert explicit.code == 3 and "--rs485 soft: the device has no RTS modem line" in \
            explicit.err, explicit


def test_device_url_is_not_a_file() -> None:
    url = "tcp://127.0.0.1:1"
    res = run_proc("ports", "--device", url)
    assert res.code == 0, res
    (line,) = [ln for ln in res.lines() if ln.startswith(url)]
    assert "a network port: not probed" in line and "No such file" not in line
    js = run_proc("ports", "--device", url, "--json")
    rows = [json.loads(ln) for ln in js.lines()]
    (row,) = [r for r in rows if r["device"] == url]
    assert row["rs485"] == "network" and "error" not in row


@pytest.mark.parametrize("option", ["--check", "--device"])
def test_empty_path_is_a_usage_error(option: str) -> None:
    res = run_proc("ports", option, "")
    assert res.code == 2, res
    assert f"argument {option}: needs a device path or a tcp:// / rfc2217:// URL, not ''" in res.err
