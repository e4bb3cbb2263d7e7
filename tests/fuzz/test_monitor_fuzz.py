"""``fap_py.monitor`` under hypothesis: any bytes in any chunks for every
protocol give records that tile the input once, in order, garbage records
of at most GARBAGE_MAX bytes, times that never go backwards; the capture
reader takes any file content and either streams it or raises a
CaptureFormatError/PortError naming the file (never another exception).
Runs in seconds (MONITOR_FUZZ_EXAMPLES scales it); part of .ci/fuzz.sh."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import List

import pytest

try:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
except ImportError:                         # CI installs it: a missing tool fails there
    if os.environ.get("CI"):
        raise
    pytest.skip("hypothesis not installed", allow_module_level=True)

from fap_py.errors import FapError
from fap_py.monitor import Monitor
from fap_py.monitor.decoders import GARBAGE_MAX, HOLD_MAX, PROTOCOLS
from fap_py.monitor.sources import capture_file
from fap_py.vbus import CaptureFormatError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python" / "monitor"))
from monitor_helpers import VECTOR_FILES  # the monitor tests' vector list

EXAMPLES = int(os.environ.get("MONITOR_FUZZ_EXAMPLES", "150"))


def _frames() -> List[bytes]:
    out = []
    for path in VECTOR_FILES.values():
        doc = json.loads(path.read_text(encoding="utf-8"))
        out += [bytes.fromhex(v["frame"]) for v in doc.get("valid", []) + doc.get("invalid", [])]
    return out


FRAMES = _frames()
#: bytes that start frames: the fuzzer reaches the codecs' edges sooner
SPICE = st.sampled_from([b"\xff", b"\xff\xff", b"\x10\x02", b"\x10\x03", b"\x10", b"\x96",
                         b"\xa9", b"cCtRsFeF", b"c"])
STREAM = st.lists(st.one_of(st.sampled_from(FRAMES), st.binary(max_size=24), SPICE),
                  max_size=40).map(b"".join)
SETTINGS = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])


def decode(protocol: str, data: bytes, cuts: List[int], t0: float, char_s: float) -> list:
    mon = Monitor(protocol, 9600)
    recs, pos, t = [], 0, t0
    for cut in sorted({c % (len(data) + 1) for c in cuts}) + [len(data)]:
        if cut > pos:
            recs += mon.feed(data[pos:cut], t, char_s, 1, 0)
            t += (cut - pos) * char_s * 0.5      # reads that overlap on the wire clock
            pos = cut
    return recs + mon.finish()


@SETTINGS
@given(st.sampled_from(PROTOCOLS + ("auto",)), STREAM, st.lists(st.integers(0, 2000), max_size=8),
       st.floats(0, 1e6), st.floats(0, 0.01))
def test_records_tile_any_stream(protocol, data, cuts, t0, char_s):
    recs = decode(protocol, data, cuts, t0, char_s)
    if len(data) < HOLD_MAX:       # longer: a crafted chain of bad candidates may overlap
        assert b"".join(r.raw for r in recs) == data
    offsets = [r.event.offset for r in recs]
    assert offsets == sorted(offsets)
    times = [r.t for r in recs]
    assert times == sorted(times)
    for r in recs:
        assert r.ok == (r.error is None)
        if r.error == "garbage":
            assert 0 < len(r.raw) <= GARBAGE_MAX


@SETTINGS
@given(st.sampled_from(PROTOCOLS), st.lists(st.sampled_from(FRAMES), max_size=10))
def test_whole_and_byte_by_byte_agree(protocol, frames):
    data = b"".join(frames)
    whole = [(r.error, r.raw) for r in decode(protocol, data, [], 0.0, 0.0)]
    single = [(r.error, r.raw) for r in decode(protocol, data, list(range(len(data))), 0.0, 0.0)]
    assert [w for w in whole if w[0] is None] == [s for s in single if s[0] is None]


LINE = st.one_of(
    st.builds(lambda t, p, bs: f"{t} {p} " + " ".join(f"{b:02x}" for b in bs),
              st.integers(-10, 2**64), st.integers(-10, 300), st.binary(max_size=8)),
    st.builds(lambda b: f"# fap-vbus-capture 1 ports=2 baud={b} echo=0 seed=0",
              st.one_of(st.integers(-5, 2**40), st.text(max_size=4))),
    st.builds(lambda k, t: f"# {k} t={t}", st.text("abc", min_size=1, max_size=3),
              st.integers(-5, 10**9)),
    st.text(max_size=30),
)


def _read(path: Path) -> int:
    try:
        baud, chunks = capture_file(str(path))
        return baud + sum(len(c.data) for c in chunks)
    except CaptureFormatError as exc:
        assert str(path) in str(exc)
        return -1
    except FapError:
        return -1


@SETTINGS
@given(st.one_of(st.binary(max_size=300),
                 st.lists(LINE, max_size=12).map(lambda ls: "\n".join(ls).encode("utf-8"))))
def test_capture_reader_takes_any_file(tmp_path_factory, content):
    path = tmp_path_factory.mktemp("cap") / "fuzz.cap"
    path.write_bytes(content)
    _read(path)
