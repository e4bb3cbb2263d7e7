"""The CLI defects found in field use (issue 25, issue 26 item 8), each through the entry point."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import time
from pathlib import Path
from typing import List, Optional

import pytest

from fap_py import RS485, RS485Mode, execasync
from fap_py import Slave as FapSlave
from fap_py.g485 import SimDevice, Simulator

from .conftest import fap_cmd

LINE = RS485(mode=RS485Mode.NONE)
NONE = ("--rs485", "none")


def _start(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen(fap_cmd(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kw)


def _line(p: subprocess.Popen, timeout: float = 20) -> str:
    """The next stdout line of ``p`` within ``timeout`` (a condition, not a sleep)."""
    assert p.stdout is not None
    r, _, _ = select.select([p.stdout], [], [], timeout)
    assert r, "no output in time"
    return p.stdout.readline()


def _objs(text: str) -> List[dict]:
    return [json.loads(line) for line in text.splitlines()]


# -- issue 26 item 8: --reply ------------------------------------------------

@pytest.mark.parametrize("argv", [["exec", "slave", "--node", "3"],
                                  ["mikroc", "slave", "--address", "3"]], ids=" ".join)
def test_bad_reply_is_a_usage_error(argv: List[str], fap) -> None:
    r = fap(*argv, "--port", "/dev/null", "--reply", "zz")
    assert r.code == 2 and r.out == "", r.err
    assert r.err.splitlines() == [
        f"fap: error: argument --reply: not hex bytes: 'zz' (see 'fap {argv[0]} slave --help')"]
    if argv[0] == "mikroc":   # a mikroC message is 0..3 bytes
        r = fap(*argv, "--port", "/dev/null", "--reply", "01020304")
        assert r.code == 2 and "a reply is 0..3 bytes, not 4" in r.err


# -- defect 3: --rs485 kernel|soft on a device that cannot ------------------

RS485_COMMANDS = [
    ["exec", "master", "--node", "5", "01"], ["exec", "slave", "--node", "5"],
    ["exec", "scan", "--last", "2"], ["exec", "broadcast", "01"],
    ["fap", "master", "--slaves", "3"], ["fap", "slave", "--id", "3"],
    ["mikroc", "master", "--address", "5", "01"], ["mikroc", "slave", "--address", "5"],
    ["g485", "read", "--address", "1", "--register", "1"], ["g485", "sim", "--address", "1"],
    ["g485", "scan", "--last", "2"], ["monitor", "--idle", "0.1"],
]


@pytest.mark.parametrize("mode", ["kernel", "soft"])
@pytest.mark.parametrize("argv", RS485_COMMANDS, ids=lambda a: " ".join(a[:2]))
def test_rs485_mode_the_device_cannot_do_is_one_clear_line(argv: List[str], mode: str, fap,
                                                           bus) -> None:
    r = fap(*argv, "--port", bus.paths[0], "--rs485", mode)
    assert r.code == 3, r.err             # a port error (docs/cli.md)
    lines = r.err.splitlines()
    assert len(lines) == 1, r.err
    assert lines[0].startswith(f"fap: error: {bus.paths[0]}: --rs485 {mode}: the device has no ")
    assert "use --rs485 " in lines[0] and "Inappropriate ioctl" not in lines[0]


# -- defect 4: stdin streamed ------------------------------------------------

def test_stdin_payloads_are_sent_as_they_arrive(bus) -> None:
    with execasync.Slave(bus.paths[1], node=5, handler=lambda q: q.data, rs485=LINE).start():
        p = subprocess.Popen(fap_cmd("exec", "master", "--port", bus.paths[0], *NONE, "--node",
                                     "5", "--timeout", "1", "--json", "-"),
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        try:
            assert p.stdin is not None
            p.stdin.write("01\n")
            p.stdin.flush()
            # the reply to the first line comes while stdin is still open
            assert json.loads(_line(p)) == {"event": "reply", "node": 5, "seq": 0, "data": "01"}
            p.stdin.write("zz\n\n0304\n")
            p.stdin.close()
            p.stdin = None        # communicate() must not flush it again
            out, err = p.communicate(timeout=30)
        finally:
            p.kill()
    objs = _objs(out)
    assert objs[0] == {"event": "bad_input", "line": 2,
                       "error": "not hex bytes: 'zz' (use --text for text payloads)"}
    assert objs[1] == {"event": "reply", "node": 5, "seq": 1, "data": "0304"}   # the batch went on
    assert objs[-1]["event"] == "stats" and objs[-1]["transactions"] == 2
    assert p.returncode == 2      # some lines were not payloads (docs/cli.md)
    assert err.splitlines() == ["fap: error: 1 of 3 stdin lines were not payloads (skipped)"]


def test_an_endless_stdin_line_is_bounded(bus) -> None:
    with execasync.Slave(bus.paths[1], node=5, handler=lambda q: q.data, rs485=LINE).start():
        p = subprocess.run(fap_cmd("exec", "master", "--port", bus.paths[0], *NONE, "--node", "5",
                                   "--timeout", "1", "-"),
                           input=b"a" * 300_000 + b"\n0102\n", capture_output=True, timeout=60)
    assert p.returncode == 2
    assert p.stdout.decode().splitlines()[0] == "node 5 seq 0: 01 02"
    assert p.stderr.decode().splitlines()[0] == "fap: stdin line 1: longer than 65536 bytes; skipped"


def test_bad_stdin_line_in_human_mode(fap, bus, monkeypatch) -> None:
    import io

    with execasync.Slave(bus.paths[1], node=5, handler=lambda q: q.data, rs485=LINE).start():
        monkeypatch.setattr("sys.stdin", io.StringIO("0102\nzz\n0304\n"))
        r = fap("exec", "master", "--port", bus.paths[0], *NONE, "--node", "5", "--timeout", "1",
                "-")
    assert r.code == 2
    assert r.lines()[:2] == ["node 5 seq 0: 01 02", "node 5 seq 1: 03 04"]
    assert r.err.splitlines() == [
        "fap: stdin line 2: not hex bytes: 'zz' (use --text for text payloads); skipped",
        "fap: error: 1 of 3 stdin lines were not payloads (skipped)"]


# -- defect 5: Ctrl-C summaries, polling goes on --------------------------------

def _interrupt(p: subprocess.Popen) -> tuple:
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)
    return p.returncode, out, err


def test_exec_master_forever_ctrl_c_prints_the_summary(bus) -> None:
    with execasync.Slave(bus.paths[1], node=5, handler=lambda q: q.data, rs485=LINE).start():
        p = _start("exec", "master", "--port", bus.paths[0], *NONE, "--node", "5", "--count", "0",
                   "--interval", "0.05", "--timeout", "1", "--json", "01")
        assert json.loads(_line(p))["event"] == "reply"
        code, out, err = _interrupt(p)
    assert code == 130, err
    last = _objs(out)[-1]
    assert last["event"] == "stats" and last["interrupted"] is True and last["transactions"] >= 1


def test_exec_scan_ctrl_c_prints_the_summary(bus) -> None:
    with execasync.Slave(bus.paths[1], node=1, handler=lambda q: b"", rs485=LINE).start():
        p = _start("exec", "scan", "--port", bus.paths[0], *NONE, "--timeout", "0.3", "--json")
        assert json.loads(_line(p)) == {"event": "found", "node": 1, "reply": ""}
        code, out, err = _interrupt(p)
    assert code == 130, err
    last = _objs(out)[-1]
    assert last["event"] == "summary" and last["interrupted"] is True and last["of"] == 254
    assert last["found"] == [1] and 1 <= last["tried"] < 254


def test_g485_scan_ctrl_c_prints_the_summary(bus) -> None:
    with Simulator(bus.paths[1], [SimDevice(1)]):
        p = _start("g485", "scan", "--port", bus.paths[0], "--timeout", "0.5", "--json")
        assert json.loads(_line(p)) == {"event": "found", "address": 1}
        code, out, err = _interrupt(p)
    assert code == 130, err
    last = _objs(out)[-1]
    assert last["event"] == "summary" and last["interrupted"] is True and last["found"] == [1]


def test_fap_master_forever_ctrl_c_is_130(bus) -> None:
    with FapSlave(bus.paths[1], id=3, rs485=LINE):
        p = _start("fap", "master", "--port", bus.paths[0], *NONE, "--slaves", "3", "--count",
                   "0", "--json")
        assert json.loads(_line(p))["event"] == "ready"
        code, out, err = _interrupt(p)
    assert code == 130, err
    last = _objs(out)[-1]
    assert last["event"] == "stats" and last["interrupted"] is True


def test_fap_master_reading_stdin_ends_on_ctrl_c(bus) -> None:
    with FapSlave(bus.paths[1], id=3, rs485=LINE) as slave:
        p = subprocess.Popen(fap_cmd("fap", "master", "--port", bus.paths[0], *NONE, "--slaves",
                                     "3", "--json", "-"), stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert p.stdin is not None
            assert json.loads(_line(p))["event"] == "ready"
            p.stdin.write("0102\n")
            p.stdin.flush()
            while json.loads(_line(p))["event"] != "tx":    # sent as it arrived
                pass
            assert slave.recv(timeout=10).data == b"\x01\x02"
            code, out, err = _interrupt(p)     # waiting for the next stdin line
        finally:
            p.kill()
    assert code == 130, err
    assert _objs(out)[-1]["event"] == "stats"


def test_g485_read_forever_keeps_polling_after_a_missed_reply(fap, bus) -> None:
    r = fap("g485", "read", "--port", bus.paths[0], "--address", "9", "--register", "1",
            "--count", "3", "--interval", "0", "--timeout", "0.05", "--retries", "0", "--json")
    objs = _objs(r.out)
    assert [o["event"] for o in objs] == ["error", "error", "error", "summary"], r.out
    assert objs[-1] == {"event": "summary", "address": 9, "requests": 3, "failed": 3}
    assert r.code == 1 and r.err.splitlines() == ["fap: error: 3 of 3 reads to device 9 failed"]


def _children(pid: int) -> List[int]:
    """The soak's slave processes (``... --child ...``), not a helper an import spawns
    before the soak's signal handling is in place (ctypes' find_library)."""
    try:
        kids = [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []
    found = []
    for k in kids:
        try:
            if b"--child" in Path(f"/proc/{k}/cmdline").read_bytes().split(b"\0"):
                found.append(k)
        except OSError:
            pass
    return found


def test_soak_ctrl_c_prints_the_results_so_far() -> None:
    p = _start("soak", "--protocol", "exec", "--seconds", "120", "--slaves", "1", "--json")
    end = time.monotonic() + 30
    while not _children(p.pid) and time.monotonic() < end:   # its slave process is up
        time.sleep(0.05)
    assert _children(p.pid), "the soak started no slave"
    t0 = time.monotonic()
    code, out, err = _interrupt(p)
    assert time.monotonic() - t0 < 20          # not the 120 s
    assert code == 130, err
    res = _objs(out)
    assert len(res) == 1 and res[0]["protocol"] == "exec" and res[0]["interrupted"] is True


# -- defect 7: FAP timing defaults and the ID answer window -------------------------

def _fap_master_run(bus, *extra: str) -> List[dict]:
    with FapSlave(bus.paths[1], id=3, rs485=LINE):
        p = subprocess.run(fap_cmd("fap", "master", "--port", bus.paths[0], *NONE, "--slaves",
                                   "3,7", "--json", *extra),
                           capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    return _objs(p.stdout)


def test_fap_master_default_id_cycle_is_the_apis(bus) -> None:
    # slave 7 is absent: with the API's 15 s cycle it costs one ID window in
    # 3.5 s (the old 1 s default: a second cycle after 2 s)
    objs = _fap_master_run(bus, "--interval", "3.5")
    timeouts = [o for o in objs if o["event"] == "id_timeout" and o["slave"] == 7]
    assert len(timeouts) == 1, objs
    assert objs[-1]["event"] == "stats" and objs[-1]["id_cycles"] <= 1


def test_fap_master_id_answer_window_can_be_shortened(bus) -> None:
    objs = _fap_master_run(bus, "--interval", "1", "--id-cycle", "0.1",
                           "--id-answer-timeout", "0.05")
    timeouts = [o for o in objs if o["event"] == "id_timeout" and o["slave"] == 7]
    assert len(timeouts) >= 3, objs       # a 1 s window would allow one


# -- defect 9: wording ---------------------------------------------------------

def test_exec_no_reply_names_the_node_once(fap, bus) -> None:
    r = fap("exec", "master", "--port", bus.paths[0], *NONE, "--node", "6", "--timeout", "0.05",
            "--retries", "0", "01")
    assert r.code == 1
    assert r.lines() == ["node 6 seq 0: no reply",
                         "1 transaction, 0 retries, 1 failed, 0 corrupt frames"]
    assert r.err == "fap: error: 1 of 1 request to node 6 failed\n"


def test_invalid_argument_is_not_said_twice(bus) -> None:
    from fap_py import Master
    from fap_py.errors import InvalidValueError

    with pytest.raises(InvalidValueError) as info:
        Master(bus.paths[0], 12345, rs485=LINE)
    # issue 33: the rate and the valid ones are named, before C (once, not twice)
    assert str(info.value).startswith("baudrate 12345 is not a supported rate; supported: ")
    assert "9600" in str(info.value) and "invalid argument" not in str(info.value)


def test_bus_capture_error_names_the_file(fap, tmp_path: Path) -> None:
    r = fap("bus", "--capture", "/nonexistent/x")
    assert r.code == 3
    assert r.err == ("fap: error: /nonexistent/x: cannot write the --capture file "
                     "(No such file or directory)\n")
    r = fap("bus", "--link-dir", "/etc/passwd")
    assert r.code == 3 and r.err == ("fap: error: /etc/passwd: cannot use --link-dir "
                                     "(Not a directory)\n")


def test_mikroc_help_and_plurals(fap) -> None:
    out = fap("mikroc", "master", "--help").out
    assert "messages (0..3 bytes each) to send" in out and "bytes)s" not in out
    r = fap("exec", "decode", "00")
    assert r.out == "no exec async frame in 1 byte\n"


# -- defect 11: JSON shapes --------------------------------------------------------

def test_g485_json_objects_carry_an_event(fap, bus) -> None:
    base = ("--port", bus.paths[0], "--address", "4", "--timeout", "1", "--json")
    with Simulator(bus.paths[1], [SimDevice(4)]):
        events = []
        for argv in (["read", "--register", "7"], ["write", "--register", "8", "5"],
                     ["set", "save_eeprom"], ["error-word"], ["handshake"]):
            r = fap("g485", *argv, *base)
            assert r.code == 0, r.err
            events += [o["event"] for o in _objs(r.out)]
    assert events == ["reply", "written", "set", "reply", "reply"]


# -- defect 13 -------------------------------------------------------------------

def test_rs485_mode_prints_its_name_and_names_are_accepted(bus) -> None:
    from fap_py import Master

    with Master(bus.paths[0], slaves=[3], rs485=RS485(mode="none")) as m:
        assert str(m.rs485_mode) == "NONE" and f"{m.rs485_mode}" == "NONE"
        assert int(m.rs485_mode) == RS485Mode.NONE
    assert RS485(mode="soft").mode is RS485Mode.SOFT_RTS
    assert RS485(mode="Kernel").mode is RS485Mode.KERNEL


def _example(name: str) -> Optional[Path]:
    """A built example: under meson test the cwd is build/tests."""
    root = Path(__file__).resolve().parents[3]
    for build in (Path.cwd().parent, Path.cwd(), root / "build"):
        exe = build / "examples" / "fap" / name
        if exe.is_file() and os.access(exe, os.X_OK):
            return exe
    return None


@pytest.mark.parametrize("name", ["fap_master", "fap_slave"])
def test_fap_examples_print_a_usage_line(name: str) -> None:
    exe = _example(name)
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail(f"examples/fap/{name} not built")
        pytest.skip(f"examples/fap/{name} not built")
    for argv in (["-h"], ["/dev/null", "x"], ["/dev/null", "99"], ["a", "1", "1", "extra"]):
        p = subprocess.run([str(exe), *argv], capture_output=True, text=True, timeout=10)
        assert p.returncode == 2 and p.stderr.startswith(f"usage: {name} [device ["), argv

