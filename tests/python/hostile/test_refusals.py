"""Issue 32, items 20 and 21: hostile calls found from outside the package's walk.

Item 20, generic errors: ``g485.Parser.feed`` on a strided memoryview raised
``TypeError: can't concat memoryview to bytearray``; ``PcapWriter`` on a text
file ``TypeError: string argument expected``. Item 21, accepted where a
refusal is due: ``rs485.port_options(2**31)``, ``vbus.parse_capture`` with
``ports=x`` in the header, ``SimDevice(eeprom_path=b'\\xff\\xfe')`` and a path
in a missing directory, ``Simulator.add``/``.device`` after ``close()``, and
``Port.transact`` with nothing to send and no reply (n=0 itself is "send
only", documented). Every refusal is a fap_py.errors class with a message
saying what is wrong.
"""
from __future__ import annotations

import array
import io
import os
import select
import time
from pathlib import Path
from typing import Any, Callable, Tuple, Type

import pytest

from fap_py import rs485, vbus
from fap_py.errors import ClosedError, FapError, FileError, InvalidTypeError, InvalidValueError
from fap_py.g485 import G485ValueError, SimDevice, Simulator
from fap_py.g485.codec import Discarded, Parser
from fap_py.monitor.pcap import PcapWriter
from fap_py.port import Port
from fap_py.rs485 import RS485, RS485Mode

pytestmark = pytest.mark.timeout(30)

LINE = RS485(mode=RS485Mode.NONE)


def refused(fn: Callable[[], Any], cls: Type[FapError], *words: str) -> FapError:
    """fn() must raise cls (a fap_py error), its message holding every word."""
    try:
        result = fn()
    except cls as exc:
        for w in words:
            assert w in str(exc), (w, str(exc))
        return exc
    except BaseException as exc:            # a generic error escaped
        pytest.fail(f"{type(exc).__name__} instead of {cls.__name__}: {exc!r}")
    pytest.fail(f"accepted, returned {result!r}")


# -- item 20 ------------------------------------------------------------------------------

def test_parser_feed_takes_every_bytes_like_object() -> None:
    data = b"\x00\x01garbage\xff"
    want = Parser().feed(data)
    assert want and all(isinstance(e, Discarded) for e in want)
    doubled = bytes(b for c in data for b in (c, 0xEE))
    for like in (bytearray(data), memoryview(data), memoryview(doubled)[::2],
                 memoryview(data).cast("B", (1, len(data))), array.array("B", data)):
        assert Parser().feed(like) == want, type(like)


@pytest.mark.parametrize("bad", ["text", 5, None, 1.5, [1, 2], object()])
def test_parser_feed_refuses_what_is_not_bytes(bad: Any) -> None:
    refused(lambda: Parser().feed(bad), G485ValueError, "feed takes bytes")


def test_parser_feed_refuses_a_released_view() -> None:
    view = memoryview(b"\xff\xff")
    view.release()
    refused(lambda: Parser().feed(view), G485ValueError, "feed", "released")


def test_pcap_writer_refuses_a_text_file_at_construction(tmp_path: Path) -> None:
    with open(tmp_path / "t.pcap", "w") as text:
        refused(lambda: PcapWriter(text), InvalidTypeError, "binary file", "'wb'")
    refused(lambda: PcapWriter(io.StringIO()), InvalidTypeError, "binary file")

    class TextLike:                      # not an io.TextIOBase, and takes only str
        def write(self, s: str) -> int:
            return len(s + "")

        def flush(self) -> None:
            pass

    refused(lambda: PcapWriter(TextLike()), InvalidTypeError, "does not take bytes")


def test_pcap_writer_refuses_closed_read_only_and_full_files(tmp_path: Path) -> None:
    path = tmp_path / "o.pcap"
    closed = open(path, "wb")
    closed.close()
    refused(lambda: PcapWriter(closed), InvalidValueError, "closed")
    with open(path, "rb") as read_only:
        refused(lambda: PcapWriter(read_only), InvalidValueError, "not open for writing")
    if os.path.exists("/dev/full"):
        with open("/dev/full", "wb", buffering=0) as full:
            err = refused(lambda: PcapWriter(full), FileError, "/dev/full", "pcap file")
            assert err.errno == 28          # ENOSPC
    out = io.BytesIO()
    PcapWriter(out)                      # a binary file is still fine
    assert out.getvalue()[:4] == b"\xd4\xc3\xb2\xa1"


# -- item 21 ------------------------------------------------------------------------------

@pytest.mark.parametrize("baud", [2**31, 12345, 4000001, 2**32 - 1])
def test_port_options_refuses_a_rate_the_port_layer_does_not_open(baud: int) -> None:
    refused(lambda: rs485.port_options(baud), InvalidValueError, f"baudrate {baud}", "115200")
    refused(lambda: RS485().apply_to(rs485.port_options(9600), baud), InvalidValueError,
            f"baudrate {baud}")


def test_port_options_takes_every_rate_the_port_layer_opens() -> None:
    rates = rs485.baud_rates()
    assert 9600 in rates and 115200 in rates and list(rates) == sorted(rates)
    for r in rates:
        assert rs485.port_options(r).baud == r


def test_port_refuses_the_rate_before_opening(tmp_path: Path) -> None:
    # the path does not exist: the rate is refused first, in Python
    refused(lambda: Port(str(tmp_path / "nope"), 2**31), InvalidValueError, "not a supported rate")


HEAD = "# fap-vbus-capture 1 "


@pytest.mark.parametrize("fields,why", [
    ("ports=x baud=0 echo=0 seed=0", "header ports=x"),
    ("ports=1", "header ports=1"), ("ports=65", "header ports=65"),
    ("ports=-2", "header ports=-2"), ("ports=2 baud=x", "header baud=x"),
    ("ports=2 baud=4294967296", "header baud=4294967296"), ("ports=2 echo=yes", "header echo=yes"),
    ("ports=2 seed=1_0", "header seed=1_0"), ("ports=\u0663", "header ports="),
])
def test_parse_capture_refuses_a_bad_header(fields: str, why: str) -> None:
    refused(lambda: vbus.parse_capture([HEAD + fields, "10 0 01"]), vbus.CaptureFormatError,
            "line 1", why)


def test_parse_capture_refuses_a_second_header_and_ports_beyond_it(tmp_path: Path) -> None:
    refused(lambda: vbus.parse_capture([HEAD + "ports=2", HEAD + "ports=3"]),
            vbus.CaptureFormatError, "line 2", "second capture header")
    refused(lambda: vbus.parse_capture([HEAD + "ports=2", "10 0 01", "20 2 02"]),
            vbus.CaptureFormatError, "line 3", "port 2", "ports=2")
    cap = tmp_path / "c.cap"
    cap.write_text(HEAD + "ports=x\n10 0 01\n", encoding="ascii")
    refused(lambda: vbus.read_capture(cap), vbus.CaptureFormatError, str(cap), "ports=x")
    good = vbus.parse_capture([HEAD + "ports=3 baud=9600 echo=1 seed=18446744073709551615 new=key",
                               "10 2 01", "# overflow t=20 port=9"])
    assert good.header["ports"] == "3" and good.header["new"] == "key"
    assert good.data_from(2) == b"\x01" and good.events_of("overflow")


def test_sim_device_refuses_undecodable_and_homeless_eeprom_paths(tmp_path: Path) -> None:
    refused(lambda: SimDevice(eeprom_path=b"\xff\xfe"), G485ValueError, "not a valid UTF-8",
            "xff")
    refused(lambda: SimDevice(eeprom_path="ee\udcffprom.json"), G485ValueError, "UTF-8")
    refused(lambda: SimDevice(eeprom_path=tmp_path / "missing" / "ee.json"), G485ValueError,
            "does not exist", "missing")
    (tmp_path / "file").write_text("")
    refused(lambda: SimDevice(eeprom_path=tmp_path / "file" / "ee.json"), G485ValueError,
            "Not a directory")
    ok = SimDevice(eeprom_path=os.fsencode(tmp_path / "ee.json"))
    assert ok.eeprom_path == str(tmp_path / "ee.json")


@pytest.mark.parametrize("end", ["close", "stop"])
def test_simulator_refuses_add_and_device_once_closed(pty_pair: Tuple[int, str], end: str) -> None:
    _, name = pty_pair
    sim = Simulator(name, [SimDevice(3)], rs485=LINE)
    assert sim.device(3).address == 3
    sim.start()
    getattr(sim, end)()
    refused(lambda: sim.add(SimDevice(4)), ClosedError, "simulator stopped")
    refused(lambda: sim.device(3), ClosedError, "simulator stopped")
    refused(sim.start, ClosedError, "simulator stopped")
    sim.close()                          # a second close is harmless
    assert [d.address for d in sim.devices] == [3]


def test_port_transact_n0_is_send_only_and_an_empty_no_op_is_refused(
        pty_pair: Tuple[int, str]) -> None:
    far, name = pty_pair
    with Port(name, rs485=LINE) as port:
        assert port.transact(b"hi", 0, 0) == b""          # send only: written, nothing awaited
        t0 = time.monotonic()
        assert port.transact(b"!", 0, time.monotonic_ns() + 5_000_000_000) == b""
        assert time.monotonic() - t0 < 1.0                # the deadline is not waited out
        got = b""
        while len(got) < 3 and select.select([far], [], [], 5.0)[0]:
            got += os.read(far, 16)
        assert got == b"hi!"
        refused(lambda: port.transact(b"", 0, 0), InvalidValueError, "nothing to send",
                "send only")
        refused(lambda: port.transact(bytearray(), 0, 0), InvalidValueError, "nothing to send")
