"""The fap_py target's one measurement (bench/fap_py/bench_fap_py.py ``paired``) and its
row (bench/verdicts.py ``python_rows``), on synthetic runs: no bus, no timing.

``bench/`` is not part of the package: it is imported from the checkout.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Dict, Iterator, List

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _bench_path() -> Iterator[None]:
    saved = list(sys.path)
    # the checkout's bench/ last: fap_py itself must stay the installed package (with _native)
    sys.path[:0] = [str(ROOT / "bench" / "fap_py")]
    sys.path.append(str(ROOT))
    try:
        yield
    finally:
        sys.path[:] = saved


def _fake_runs(fp: Any, monkeypatch: pytest.MonkeyPatch, rates: Dict[str, List[float]],
               fail_at: int = -1) -> List[str]:
    """run_c / run_py replaced: each API returns its next rate (wall = count / rate);
    the call numbered ``fail_at`` fails as a lost frame does. Returns the call order."""
    calls: List[str] = []

    def result(api: str, mode: str, count: int) -> Any:
        calls.append(api)
        if len(calls) - 1 == fail_at:
            if api == "c":
                raise SystemExit("bench_fapx_c rt failed: master rx: Connection timed out")
            raise fp.FapTimeoutError("recv: no message within 10 s")
        rate = rates[api].pop(0)
        return fp.Result(mode, 16, api, count, count / rate, count / rate / 10, polls=2 * count)

    monkeypatch.setattr(fp, "run_c", lambda exe, paths, mode, count, size: result("c", mode, count))
    monkeypatch.setattr(fp, "run_py", lambda paths, mode, count, size: result(
        "aio" if "asyncio" in mode else "py", mode, count))
    return calls


def test_paired_median_of_per_pair_ratios_order_rotated(monkeypatch: pytest.MonkeyPatch) -> None:
    import bench_fap_py as fp
    # a load swing moves both sides of a pair: the per-pair ratios stay 0.8, 0.8, 0.5
    rates = {"c": [1000.0, 4000.0, 2000.0], "py": [800.0, 3200.0, 1000.0],
             "aio": [500.0, 2000.0, 1000.0]}
    calls = _fake_runs(fp, monkeypatch, rates)
    res = fp.paired(Path("x"), ["a", "b"], pairs=3, count=100)
    assert calls == ["c", "py", "aio", "py", "aio", "c", "aio", "c", "py"]
    assert res["pairs"] == 3 and res["dropped"] == []
    assert res["ratio"] == pytest.approx(0.8) and res["ratio_min"] == pytest.approx(0.5)
    assert res["ratio_max"] == pytest.approx(0.8) and res["aio_ratio"] == pytest.approx(0.5)
    assert res["rate"]["c"] == pytest.approx(2000.0) and res["polls"]["py"] == pytest.approx(2.0)
    assert res["load_before"].count(" ") == 2
    text = fp.paired_report(res)
    assert "median per-pair ratio fap_py/C 0.80 (range 0.50-0.80)" in text and "polls/msg" in text


def test_paired_drops_a_pair_whose_frame_was_lost(monkeypatch: pytest.MonkeyPatch) -> None:
    import bench_fap_py as fp
    rates = {"c": [1000.0, 1000.0, 1000.0], "py": [900.0, 700.0], "aio": [500.0, 500.0]}
    calls = _fake_runs(fp, monkeypatch, rates, fail_at=1)   # the first pair's fap_py run
    res = fp.paired(Path("x"), ["a", "b"], pairs=2, count=100)
    assert calls == ["c", "py", "py", "aio", "c", "aio", "c", "py"]
    assert res["pairs"] == 2 and len(res["dropped"]) == 1 and "10 s" in res["dropped"][0]
    assert res["ratio"] == pytest.approx(0.8)
    assert "dropped a pair" in fp.paired_report(res)


def test_paired_gives_up_when_every_pair_fails(monkeypatch: pytest.MonkeyPatch) -> None:
    import bench_fap_py as fp

    def lost(*a: Any) -> Any:
        raise SystemExit("bench_fapx_c rt failed")

    monkeypatch.setattr(fp, "run_c", lost)
    with pytest.raises(RuntimeError, match="every pair failed"):
        fp.paired(Path("x"), ["a", "b"], pairs=2, count=10)


def test_python_row_reads_the_pairs() -> None:
    from bench import verdicts
    rt = {"c_rate": 5000.0, "py_rate": 3600.0, "c_cpu_us": 100.0, "py_cpu_us": 130.0,
          "ratio": 0.74, "ratio_min": 0.5, "ratio_max": 1.2, "pairs": 11, "dropped": 1,
          "c_polls": 1.5, "py_polls": 2.0, "load_before": "1 1 1", "load_after": "2 2 2"}
    (row,) = verdicts.python_rows({"python": {"round-trip": rt}})
    assert row.value == pytest.approx(74.0) and row.met is True
    assert "11 interleaved pairs, 1 void" in row.note and "2.00 vs 1.50" in row.note
    assert "load 1 1 1 -> 2 2 2" in row.note
    (old,) = verdicts.python_rows({"python": {"round-trip": {"c_rate": 1000.0, "py_rate": 600.0}}})
    assert old.value == pytest.approx(60.0) and old.met is False and "one pair" in old.note
