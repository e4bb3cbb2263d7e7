"""``fap bus``'s per-port view reads its capture through vbus.iter_capture (the
format's one parser): complete lines only, a line still being written waits."""
from __future__ import annotations

from pathlib import Path

import pytest

from fap_py.commands.bus import _CaptureTail
from fap_py.vbus import CaptureFormatError, read_capture

HEAD = "# fap-vbus-capture 1 ports=3 baud=9600 echo=0 seed=0\n"
LINES = ["1000 0 01 02 03\n", "2000 1 0a\n", "# collision t=2500 ports=0,1\n",
         "3000 2 ff ff\n", "# fault t=3100 port=2 kind=bit\n", "# overflow t=3200 port=9\n",
         "4000 0 04\n"]


def test_tail_counts_what_read_capture_reads(tmp_path: Path) -> None:
    cap = tmp_path / "bus.cap"
    text = HEAD + "".join(LINES)
    split = len(HEAD) + len(LINES[0]) + 4        # in the middle of the second data line
    cap.write_text(text[:split])
    tail = _CaptureTail(str(cap), 3)
    try:
        tail.poll()
        assert tail.tx == [1, 0, 0] and tail.bytes == [3, 0, 0]   # the cut line waits
        with cap.open("a") as fh:
            fh.write(text[split:])
        tail.poll()
    finally:
        tail.close()
    whole = read_capture(cap)
    assert tail.tx == [sum(r.port == p for r in whole.records) for p in range(3)] == [2, 1, 1]
    assert tail.bytes == [len(whole.data_from(p)) for p in range(3)] == [4, 1, 2]
    assert tail.errors == [1, 1, 1]               # collision 0,1; fault 2; port 9 is no port


def test_a_bad_line_is_the_parsers_error(tmp_path: Path) -> None:
    cap = tmp_path / "bus.cap"
    cap.write_text(HEAD + "1000 0 zz\n")
    tail = _CaptureTail(str(cap), 2)
    try:
        with pytest.raises(CaptureFormatError):
            tail.poll()
    finally:
        tail.close()
