"""Issue 26 items 5, 9, 11, 13 (the parts outside the monitor and the bridge):
files named by the user are read bounded, paths are checked whole, the G485
simulator and codec refuse bad values, bytes-like input is accepted.

Each case is the call the issue names; before the fix it hung, raised a
generic exception or silently accepted the value.
"""
from __future__ import annotations

import array
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable, Tuple

import pytest

from fap_py import execasync, fap, mikroc, vbus
from fap_py.errors import ClosedError, FapError, FileError, FrameError, InvalidValueError, PortError
from fap_py.g485 import G485Master, codec
from fap_py.g485.device import SimDevice
from fap_py.g485.errors import G485ValueError
from fap_py.g485.simulator import Simulator
from fap_py.port import Port
from fap_py.rs485 import RS485, RS485Mode

pytestmark = pytest.mark.timeout(30)
LINE = RS485(mode=RS485Mode.NONE)


def raises(exc: type, fn: Callable[[], Any]) -> BaseException:
    with pytest.raises(exc) as info:
        fn()
    return info.value


# -- files named by the user (item 5) ------------------------------------------------

def test_read_capture_refuses_endless_and_odd_files(tmp_path: Path) -> None:
    for path in ("/dev/zero", "/dev/null", str(tmp_path)):
        raises(FileError, lambda: vbus.read_capture(path))
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)                       # nobody writes: the open must not block
    raises(FileError, lambda: vbus.read_capture(fifo))
    raises(FileError, lambda: vbus.read_capture(tmp_path / "missing"))
    raises(InvalidValueError, lambda: vbus.read_capture("a\0b"))


def test_read_capture_size_bound(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    cap = tmp_path / "c.txt"
    cap.write_text("# fap-vbus-capture 1 ports=2\n0 0 01 02\n", encoding="ascii")
    assert vbus.read_capture(cap).data_from(0) == b"\x01\x02"
    monkeypatch.setattr(vbus, "MAX_CAPTURE_BYTES", 10)
    err = raises(FileError, lambda: vbus.read_capture(cap))
    assert "more than the 10" in str(err)


def test_eeprom_path_checked(tmp_path: Path) -> None:
    for bad in ("", "a\0b", str(tmp_path), "/dev/null", "/dev/zero", 5):
        raises(G485ValueError, lambda: SimDevice(eeprom_path=bad))
    big = tmp_path / "big.json"
    big.write_bytes(b" " * ((1 << 20) + 1))
    raises(G485ValueError, lambda: SimDevice(eeprom_path=big))
    ok = SimDevice(eeprom_path=tmp_path / "new.json")      # created at the first save
    assert ok.eeprom_path == str(tmp_path / "new.json")


# -- paths (items 9, 13) -----------------------------------------------------------------

def test_non_utf8_port_path_is_a_port_error() -> None:
    for make in (lambda: execasync.Master(b"\xff\xfe", rs485=LINE),
                 lambda: execasync.Slave(b"\xff\xfe", node=1, handler=bytes, rs485=LINE),
                 lambda: mikroc.Master(b"\xff\xfe", rs485=LINE),
                 lambda: mikroc.Slave(b"\xff\xfe", address=1, rs485=LINE),
                 lambda: fap.Master(b"\xff\xfe", rs485=LINE)):
        err = raises(PortError, make)
        assert err.errno == 2, err


@pytest.mark.parametrize("cmd", [["exec", "scan"], ["mikroc", "master", "--address", "1"]])
def test_cli_non_utf8_port_exit_3(cmd: list) -> None:
    argv = [sys.executable, "-m", "fap_py", *cmd, "--port", os.fsdecode(b"/nonexistent\xff")]
    r = subprocess.run([os.fsencode(a) for a in argv], capture_output=True, timeout=60)
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert b"internal error" not in r.stderr


def test_vbus_nul_in_capture_and_link_dir(tmp_path: Path) -> None:
    os.chdir(tmp_path)
    raises(InvalidValueError, lambda: vbus.VirtualBus(ports=2, capture="a\0b"))
    raises(InvalidValueError, lambda: vbus.VirtualBus(ports=2, link_dir="a\0b"))
    assert not (tmp_path / "a").exists()


# -- the port (item 13) ---------------------------------------------------------------------

def test_port_read_bounds_like_read_until(pty_pair: Tuple[int, str]) -> None:
    _, name = pty_pair
    with Port(name, rs485=LINE) as port:
        for n in (-5, 0, 2**64, 4097):
            raises(InvalidValueError, lambda: port.read(n))
        for d in (-1, 2**64):
            raises(InvalidValueError, lambda: port.read(4, deadline_ns=d))
        assert port.read(4) == b""


def test_port_write_takes_every_bytes_like(pty_pair: Tuple[int, str]) -> None:
    far, name = pty_pair
    with Port(name, rs485=LINE) as port:
        strided = memoryview(b"abcdef")[::2]            # not contiguous
        assert port.write(strided) == 3
        assert port.write(bytearray(b"g")) == 1
        assert port.write(memoryview(array.array("H", [0x6968]))) == 2
        assert port.send(strided) == 3
        assert port.send(bytearray(b"j")) == 1
        got = b""
        while len(got) < 10:
            try:
                got += os.read(far, 64)
            except BlockingIOError:
                pass
        assert got == b"aceg" + b"hi" + b"ace" + b"j"


# -- mikroC (item 13) -------------------------------------------------------------------------

def test_mikroc_decode_exactly_one_frame() -> None:
    frame = mikroc.encode(3, b"ab")
    assert mikroc.decode(frame).data == b"ab"
    assert mikroc.decode(memoryview(frame)).data == b"ab"
    for bad in (frame + b"\x00", b"\x00" + frame, frame + frame):
        raises(FrameError, lambda: mikroc.decode(bad))


def test_bytes_like_everywhere() -> None:
    strided = memoryview(b"aXbXc")[::2]
    assert mikroc.decode(mikroc.encode(1, strided)).data == b"abc"
    frame = execasync.encode(1, strided)
    assert execasync.Decoder().feed(memoryview(frame * 2)[::1])[0].data == b"abc"
    assert mikroc.Decoder().feed(memoryview(mikroc.encode(2, b"x") + b"zz")[::1])[0].data == b"x"


# -- G485 simulator and codec (item 11) -------------------------------------------------------

def test_g485_codec_values() -> None:
    for bad in ("1", -1, 2**64, 1.0, None, True):
        raises(G485ValueError, lambda: codec.describe_error_word(bad))
    assert codec.describe_error_word(0) == "none"
    assert "BAD_CHECK" in codec.describe_error_word(1)


def test_g485_master_values(pty_pair: Tuple[int, str]) -> None:
    raises(G485ValueError, lambda: G485Master(port=1000000))
    _, name = pty_pair
    with G485Master(name, rs485=LINE) as m:
        for bad in ("x", 0, 127, -1, None, 1.5):
            raises(G485ValueError, lambda: m.believed_check_byte(bad))
        assert m.believed_check_byte(5) is None


def test_g485_simulator_values(pty_pair: Tuple[int, str]) -> None:
    _, name = pty_pair
    sim = Simulator(name, [SimDevice(3)], rs485=LINE)
    assert sim.device(3).address == 3
    for bad in (99, 0, "3", None):
        err = raises(G485ValueError, lambda: sim.device(bad))
        assert not isinstance(err, KeyError)
    sim.start()
    sim.stop()
    raises(ClosedError, sim.start)
    assert isinstance(ClosedError("x"), FapError)
