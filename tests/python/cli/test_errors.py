"""One error style for every command: `fap: error: ...` on one line, documented exit codes."""
from __future__ import annotations

import json
from typing import List

import pytest

from fap_py.commands._options import baud_rates

from .conftest import run_proc

# every command that takes --baud, with its other required arguments
BAUD_COMMANDS: List[List[str]] = [
    ["bus"],
    ["demo"],
    ["exec", "master", "--port", "/dev/null", "--node", "1"],
    ["exec", "broadcast", "--port", "/dev/null"],
    ["exec", "slave", "--port", "/dev/null", "--node", "1"],
    ["exec", "scan", "--port", "/dev/null"],
    ["fap", "master", "--port", "/dev/null", "--slaves", "3"],
    ["fap", "slave", "--port", "/dev/null", "--id", "3"],
    ["mikroc", "master", "--port", "/dev/null", "--address", "5"],
    ["mikroc", "slave", "--port", "/dev/null", "--address", "5"],
    ["g485", "sim", "--port", "/dev/null", "--address", "1"],
    ["g485", "read", "--port", "/dev/null", "--address", "1", "--register", "1"],
    ["g485", "scan", "--port", "/dev/null"],
    ["monitor", "--port", "/dev/null"],
    ["soak", "--protocol", "mikroc"],
]


@pytest.mark.parametrize("argv", BAUD_COMMANDS, ids=lambda a: " ".join(a[:2]))
def test_bad_baud_is_a_usage_error_listing_the_rates(argv: List[str], fap) -> None:
    r = fap(*argv, "--baud", "12345")
    assert r.code == 2 and r.out == ""
    lines = r.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("fap: error: argument --baud: ")
    assert "unsupported baud rate '12345'" in lines[0]
    # the rates come from the C core's table
    rates = baud_rates()
    assert 9600 in rates and 115200 in rates and 12345 not in rates
    assert "supported: " + ", ".join(map(str, rates)) in lines[0]


def test_baud_rates_are_the_c_table() -> None:
    """Every listed rate opens a real pty through the port layer; a rate off
    the list is refused by it (so the CLI check and the C check agree)."""
    import errno

    from fap_py._native import ffi, lib
    from fap_py.vbus import VirtualBus

    rates = baud_rates()
    assert list(rates) == sorted(rates) and len(rates) > 10

    def open_at(path: str, rate: int) -> int:
        po = ffi.new("fap_port_options *")
        lib.fap_port_options_init(po)
        po.baud = rate
        po.rs485_mode = lib.FAP_RS485_NONE
        out = ffi.new("fap_port **")
        rc = lib.fap_port_open(out, path.encode(), po)
        if rc == 0:
            lib.fap_port_close(out[0])
        return rc

    with VirtualBus(ports=2) as b:
        for rate in rates:
            assert open_at(b.paths[0], rate) == 0, rate
        assert open_at(b.paths[0], 12345) == -errno.EINVAL


def test_usage_errors(fap) -> None:
    r = fap("exec", "master", "--port", "x")           # --node missing
    assert r.code == 2 and r.err.startswith("fap: error: ") and len(r.err.splitlines()) == 1
    r = fap("exec", "master", "--port", "x", "--node", "3", "--rs485", "sideways")
    assert r.code == 2 and "invalid choice" in r.err
    r = fap("nosuch")
    assert r.code == 2 and r.err.startswith("fap: error: ")
    r = fap("fap", "master", "--port", "x", "--slaves", "3", "--to", "4", "00")
    assert r.code == 2 and r.err == "fap: error: --to 4 is not one of --slaves [3]\n"
    r = fap("exec", "master", "--port", "x", "--node", "3", "zz")
    assert r.code == 2 and "not hex bytes" in r.err


def test_every_port_error_exits_3() -> None:
    """Busy, gone and cannot-open are all PortErrors (fap_py.errors), all exit 3."""
    import errno

    from fap_py import errors, port
    from fap_py.commands._options import EXIT_PORT, exit_code_for

    assert port.PortBusyError is errors.PortBusyError and port.PortGoneError is errors.PortGoneError
    busy = errors.error_from_code(-errno.EBUSY, "open", "/dev/ttyX")
    gone = errors.error_from_code(-errno.EIO, "read", "/dev/ttyX")
    missing = errors.error_from_code(-errno.ENOENT, "open", "/dev/ttyX")
    assert type(busy) is errors.PortBusyError and "busy" in str(busy)
    assert type(gone) is errors.PortGoneError and type(missing) is errors.PortError
    assert [exit_code_for(e) for e in (busy, gone, missing)] == [EXIT_PORT] * 3


def test_port_errors_exit_3_one_line(fap, tmp_path) -> None:
    missing = str(tmp_path / "nope")
    for argv in (["exec", "master", "--port", missing, "--node", "1", "00"],
                 ["fap", "slave", "--port", missing, "--id", "3"],
                 ["mikroc", "master", "--port", missing, "--address", "5"],
                 ["g485", "read", "--port", missing, "--address", "1", "--register", "1"]):
        r = fap(*argv)
        assert r.code == 3, (argv, r.err)
        assert r.err.count("\n") == 1 and r.err.startswith("fap: error: ")
        assert "Traceback" not in r.err and "No such file" in r.err, r.err


def test_debug_shows_the_traceback_and_v_anywhere(fap, tmp_path) -> None:
    missing = str(tmp_path / "nope")
    r = fap("exec", "master", "--port", missing, "--node", "1", "--debug")
    assert r.code == 3 and "Traceback" in r.err and r.err.rstrip().endswith("No such file or directory")
    for argv in (["-v", "version"], ["version", "-v"], ["version", "-vv"],
                 ["--debug", "version"], ["-v", "version", "--verbose"]):
        assert fap(*argv).code == 0, argv


def test_bus_failure_exit_1(fap, bus) -> None:
    r = fap("exec", "master", "--port", bus.paths[0], "--rs485", "none", "--node", "9",
            "--timeout", "0.02", "--retries", "0", "--json", "01")
    assert r.code == 1
    objs = [json.loads(line) for line in r.lines()]
    assert objs[0]["event"] == "error" and objs[0]["node"] == 9
    assert objs[-1]["event"] == "stats" and objs[-1]["failures"] == 1
    assert r.err.startswith("fap: error: ") and r.err.count("\n") == 1


def test_interrupt_exit_130(tmp_path) -> None:
    import signal
    import subprocess

    from .conftest import fap_cmd

    with __import__("fap_py.vbus", fromlist=["VirtualBus"]).VirtualBus(ports=2) as b:
        p = subprocess.Popen(fap_cmd("exec", "master", "--port", b.paths[0], "--rs485", "none",
                                     "--node", "9", "--count", "0", "--interval", "0.05",
                                     "--timeout", "0.01", "--retries", "0", "--json"),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert json.loads(p.stdout.readline())["event"] == "error"   # it is running
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    assert p.returncode == 130, err
    assert "Traceback" not in err


def test_help_exit_0_and_version(fap) -> None:
    assert fap("--help").code == 0
    r = fap("--version")
    assert r.code == 0 and r.out.startswith("fap_py ")
    r = run_proc("version", "--json")
    assert r.code == 0 and set(json.loads(r.out)) == {"event", "fap_py", "libfap"}
