"""The monitor's one adapter over the C codec table (fap_py._codec): the vectors
decode through it with their fields, reasons and raw bytes; byte at a time equals all
at once; the rows encode what they decode; the monitor reaches C only through the
public table (no internal lf_* declaration in the cdefs); old names still resolve."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from monitor_helpers import ROOT, stream, vectors

from fap_py import _codec, _protocols
from fap_py.errors import InvalidTypeError, InvalidValueError
from fap_py.monitor import decoders, pcap
from fap_py.monitor.decoders import make_decoder

C_ROWS = list(_codec.names())


def test_the_table_has_a_row_per_c_protocol():
    assert C_ROWS == ["fap", "exec", "mikroc"]
    assert _codec.find("execasync") is _codec.find("exec")
    for bad, exc in ((None, InvalidTypeError), ("modbus", InvalidValueError), ("fap\0", InvalidValueError)):
        with pytest.raises(exc):
            _codec.find(bad)


@pytest.mark.parametrize("protocol", C_ROWS)
def test_vectors_through_the_adapter(protocol):
    codec = _codec.find(protocol)
    for v in vectors(protocol):
        dec = codec.decoder(115200)
        items = dec.feed(v.frame, 1) + dec.finish()
        if v.ok:
            (f,) = items
            assert isinstance(f, _codec.Frame) and f.offset == 0 and f.raw == v.frame, v.name
            assert f.data.hex() == v.fields["data"], v.name
            values = tuple(f.fields.values())
            assert codec.encode(values, f.data) == v.frame, v.name
        else:
            assert all(isinstance(i, _codec.Reject) for i in items), v.name
            assert items[0].reason == v.reason and items[0].offset == 0, v.name


@pytest.mark.parametrize("protocol", C_ROWS)
def test_byte_at_a_time_equals_all_at_once(protocol):
    data = stream(protocol)

    def run(step: int) -> list:
        dec = _codec.find(protocol).decoder()
        out = []
        for i in range(0, len(data), step):
            out += dec.feed(data[i:i + step], 1)
        out += dec.finish()
        # garbage is reported as it comes: compare the frames and rejects
        return [(type(i).__name__, i.offset, i.raw) for i in out
                if not (isinstance(i, _codec.Reject) and i.reason == "garbage")]

    whole = run(len(data))
    assert whole == run(1) == run(7)
    assert sum(1 for k, _o, _r in whole if k == "Frame") == sum(1 for v in vectors(protocol) if v.ok)
    assert sum(1 for k, _o, _r in whole if k == "Reject") == sum(1 for v in vectors(protocol) if not v.ok)


def test_encode_refuses_what_no_frame_holds():
    fap = _codec.find("fap")
    with pytest.raises(InvalidValueError):
        fap.encode((9, 1, 0))               # no message 9
    with pytest.raises(InvalidValueError):
        fap.encode((1, 1))                  # three fields
    with pytest.raises(InvalidTypeError):
        fap.encode("abc")


def test_the_monitor_reaches_only_the_public_table():
    """No internal (lf_*) C symbol is declared for Python; every header the cdefs name
    is a public one (include/)."""
    cdefs = sorted((ROOT / "fap_py" / "cdef").glob("*.cdef"))
    assert cdefs
    for path in cdefs:
        text = path.read_text(encoding="utf-8")
        assert not re.search(r"\blf_\w+", text), f"{path.name} declares an internal lf_* symbol"
        for header in re.findall(r"^//\s*include:\s*(\S+)", text, re.M):
            assert (ROOT / "include" / header).exists(), f"{path.name} includes internal {header}"
    monitor = Path(decoders.__file__).parent
    for py in monitor.rglob("*.py"):
        assert not re.search(r"\blf_\w+", py.read_text(encoding="utf-8")), f"{py} names an lf_* symbol"


def test_moved_names_are_gone_and_fields_is_live():
    """The forwarding of names that moved inside this unreleased package is gone
    (CHANGELOG.md): each lives once, in its plug-in or the protocol table."""
    for old in ("FapDecoder", "ExecDecoder", "MikrocDecoder", "G485Decoder", "G485_PREAMBLE"):
        with pytest.raises(AttributeError):
            getattr(decoders, old)
    with pytest.raises(AttributeError):
        getattr(pcap, "PROTOCOL_IDS")  # noqa: B009 (the name must not resolve)
    assert _protocols.get("exec").pcap_id == 2
    assert set(decoders.FIELDS) == set(decoders.PROTOCOLS)
    assert decoders.make_decoder("fap", 9600).name == "fap"


def test_make_decoder_takes_aliases():
    assert make_decoder("execasync").name == "exec"
    with pytest.raises(InvalidValueError):
        make_decoder("modbus")
