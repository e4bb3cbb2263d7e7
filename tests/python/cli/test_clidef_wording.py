"""Issue 33 item 10, the wording items, each through the command (or, for
the API's baud, the constructor): what a user reads names the option, the
value and what is valid, in words, without Python's own text or reprs."""
from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from fap_py.execasync import encode

from .conftest import fap_cmd, run_proc

HERE = Path(__file__).resolve().parent


def test_bus_ber_is_a_probability(fap) -> None:
    for opt in ("--ber", "--drop-rate"):
        r = fap("bus", opt, "2")
        assert r.code == 2 and f"argument {opt}: must be a probability in 0..1, not '2'" in r.err
        assert " s," not in r.err and "at most 1.0 s" not in r.err


def test_mikroc_says_0_3_once(fap, bus) -> None:
    r = fap("mikroc", "master", "--port", bus.paths[0], "--address", "5", "01020304")
    assert r.code == 2, r
    assert r.err == "fap: error: a mikroC message is 0..3 bytes, not 4\n"
    assert r.err.count("0..3") == 1


def test_g485_register_data_and_count(fap, bus) -> None:
    p = ("--port", bus.paths[0], "--address", "1", "--timeout", "0.05", "--retries", "0")
    r = fap("g485", "write", *p, "--register", "8", "300")
    assert r.code == 2 and "range(" not in r.err, r
    assert r.err == "fap: error: register data must be bytes or ints 0..255, not 300\n"
    r = fap("g485", "read", *p, "--register", "1", "--registers", "0")
    assert r.code == 2 and "argument --registers: must be at least 1, not '0'" in r.err, r
    assert "count 0" not in r.err


def test_fap_slaves_listed_twice(fap, bus) -> None:
    r = fap("fap", "master", "--port", bus.paths[0], "--slaves", "3,7,3", "01")
    assert r.code == 2, r
    assert "argument --slaves: slave ID 3 listed twice: '3,7,3'" in r.err


@pytest.mark.parametrize("module, cls", [("fap_py.fap", "Master"), ("fap_py.execasync", "Master"),
                                         ("fap_py.mikroc", "Master"), ("fap_py.port", "Port")])
def test_unsupported_baud_names_the_rate_and_the_valid_ones(module: str, cls: str, bus) -> None:
    import importlib

    from fap_py.errors import InvalidValueError

    factory = getattr(importlib.import_module(module), cls)
    with pytest.raises(InvalidValueError) as info:
        factory(bus.paths[0], 12345)
    text = str(info.value)
    assert text.startswith("baudrate 12345 is not a supported rate; supported: "), text
    assert "9600" in text and "115200" in text and "Invalid argument" not in text


def test_plurals(tmp_path: Path) -> None:
    cap = tmp_path / "one.cap"
    frame = encode(5, b"A", 1)
    cap.write_text(f"# fap-vbus-capture 1 ports=2 baud=9600 echo=0 seed=0\n1000 0 {frame.hex(' ')}\n")
    r = run_proc("monitor", "--capture", str(cap), "--protocol", "exec")
    assert r.code == 0, r
    assert re.search(r"^-- 1 frame, errors: none; \d+ bytes;", r.err + r.out, re.M), r
    assert "node 5: 1 frame, no errors" in r.err + r.out
    assert "1 frames" not in r.err + r.out
    one = tmp_path / "one.bin"
    one.write_bytes(frame)
    auto = run_proc("monitor", "--raw", str(one))
    assert "auto: locked on exec (1 good frame)" in auto.err, auto


def test_g485_sim_one_device_and_eeprom_errors(bus, tmp_path: Path) -> None:
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("")
    r = run_proc("g485", "sim", "--port", bus.paths[0], "--address", "1", "--eeprom-dir",
                 str(not_a_dir))
    assert r.code == 3, r
    assert r.err == (f"fap: error: {not_a_dir}: --eeprom-dir: cannot use it as the EEPROM "
                     "directory (not a directory)\n")
    eeprom = tmp_path / "eeprom"
    eeprom.mkdir()
    bad = {1: "[1, 2]\n", 2: '{"format": "fap_py.g485.eeprom/1", "registers": {"7": 300}}\n',
           3: "{x\n", 4: '{"format": "fap_py.g485.eeprom/1", "registers": []}\n'}
    for address, text in bad.items():
        (eeprom / f"g485-{address}.json").write_text(text)
    proc = subprocess.Popen(fap_cmd("g485", "sim", "--port", bus.paths[0], "--eeprom-dir",
                                    str(eeprom), *sum((["--address", str(a)] for a in bad), [])),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        ready = proc.stdout.readline()
        assert ready.startswith("ready: simulating G485 devices 1, 2, 3, 4 on "), ready
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    warnings = [ln for ln in err.splitlines() if ln.startswith("fap: warning: EEPROM file")]
    assert len(warnings) == 4, err
    assert "not an EEPROM image: a JSON list" in warnings[0]
    assert "register 7: value 300 is not 0..255" in warnings[1]
    assert "not JSON: " in warnings[2]
    assert '"registers" must be an object of register: value' in warnings[3]
    assert "attribute" not in err and "Traceback" not in err
    one = subprocess.Popen(fap_cmd("g485", "sim", "--port", bus.paths[1], "--address", "1"),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert one.stdout is not None
        assert one.stdout.readline().startswith("ready: simulating G485 device 1 on ")
    finally:
        one.send_signal(signal.SIGTERM)
        one.communicate(timeout=30)


def test_soak_report_has_no_python_reprs() -> None:
    r = run_proc("soak", "--protocol", "exec", "--seconds", "0.5", "--slaves", "1")
    assert r.code in (0, 1), r
    assert r.out.startswith("== exec\n")
    for repr_text in ("True", "False", "None", "{", "}", "'"):
        assert repr_text not in r.out, (repr_text, r.out)
    assert re.search(r"^  faults: bit_error_rate [\d.e-]+, drop_rate", r.out, re.M), r.out
    assert re.search(r"^  ok: (yes|no)$", r.out, re.M), r.out
    js = run_proc("soak", "--protocol", "exec", "--seconds", "0.3", "--slaves", "1", "--json")
    assert json.loads(js.lines()[0])["event"] == "result"


def test_rfc2217_warning_is_one_line(tmp_path: Path) -> None:
    sys.path[:0] = [str(HERE.parent / "port"), str(HERE.parent / "bridge")]
    from net_helpers import Ser2net

    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2) as bus, Ser2net(tmp_path, [("rfc2217", bus.paths[1], 19200)]) as s:
        r = run_proc("g485", "read", "--port", s.urls[0], "--address", "1", "--register", "1",
                     "--timeout", "0.1", "--retries", "0")
    warn = [ln for ln in r.err.splitlines() if ": rfc2217: " in ln]
    assert warn, r.err
    assert all(ln.startswith(f"fap: warning: {s.urls[0]}: rfc2217: ") for ln in warn), r.err
    # ser2net answered the fence after SET-CONTROL: not slow, so no option_ms advice
    assert not [ln for ln in warn if "option_ms" in ln], r.err
    assert "fap_py.port WARNING" not in r.err        # no raw logging line
