"""The bench's issue-24 plumbing, on synthetic results (no measuring, no timing).

``bench/`` is not part of the package: it is imported from the checkout.
"""
from __future__ import annotations

import json
import sys
import types
from pathlib import Path
from typing import Any, Dict, Iterator

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def _bench_path() -> Iterator[None]:
    saved = list(sys.path)
    sys.path.insert(0, str(ROOT))
    try:
        yield
    finally:
        sys.path[:] = saved        # bench.__main__ edits sys.path on import


def _summary(v: float) -> Dict[str, float]:
    return {"median": v, "min": v, "max": v}


def _results() -> Dict[str, Any]:
    def row(c: float, s: float) -> Dict[str, Any]:
        return {"client_us": _summary(c), "server_us": _summary(s), "client_wakeups": _summary(2.0),
                "server_wakeups": _summary(3.0), "client_syscalls": _summary(5.0),
                "server_syscalls": _summary(7.0)}
    paced = {"modbus": row(100.0, 40.0), "fap-poll": row(40.0, 30.0), "exec": row(50.0, 10.0),
             "mikroc": row(20.0, 20.0)}
    return {"paced": {"115200": paced, "1000000": {"fap-poll": row(1.0, 1.0)}},
            "scale": {"115200": {"slaves": {1: {"master_load": _summary(0.025),
                                                "cycles_per_s": _summary(320.0),
                                                "cpu_us_per_cycle": _summary(78.0)}}}},
            "python": {"round-trip": {"c_rate": 1000.0, "py_rate": 800.0, "c_cpu_us": 10.0,
                                      "py_cpu_us": 20.0}}}


def test_parse_stat_totals_names_and_other() -> None:
    from bench import syscalls
    text = ("# started on x\n\n120,,raw_syscalls:sys_enter,100,100.00,,\n"
            "12.5,msec,task-clock,100,100.00,0.1,CPUs utilized\n"
            "70,,syscalls:sys_enter_read,100,100.00,,\n"
            "0,,syscalls:sys_enter_ioctl,100,100.00,,\n"
            "<not counted>,,syscalls:sys_enter_poll,0,100.00,,\n"
            "30,,syscalls:sys_enter_write,100,100.00,,\n")
    assert syscalls.parse_stat(text) == {"syscalls": 120.0, "cpu": 0.0125, "read": 70.0,
                                         "write": 30.0, "other": 20.0}
    assert syscalls.parse_stat("perf: nothing\n") == {}


def test_cpu_rows_ratio_per_side_and_missing_peer() -> None:
    from bench import verdicts
    rows = {t.name: t for t in verdicts.cpu_rows(_results())}
    fap_c, fap_s = rows["cpu-fap-poll-115200-client"], rows["cpu-fap-poll-115200-server"]
    assert fap_c.value == pytest.approx(0.4) and fap_c.met is True
    assert fap_s.value == pytest.approx(0.75) and fap_s.met is False
    assert "wake-ups 3.0 vs 3.0" in fap_s.note and "syscalls 7.0 vs 7.0" in fap_s.note
    assert rows["cpu-exec-115200-server"].value == pytest.approx(0.25)
    gone = rows["cpu-fap-poll-1000000-client"]      # no libmodbus at 1 Mbaud in this run
    assert gone.value is None and gone.met is None and "libmodbus" in gone.note


def test_idle_and_python_rows() -> None:
    from bench import verdicts
    idle = {t.name: t for t in verdicts.idle_rows(_results())}
    assert idle["idle-master-1-slaves"].value == pytest.approx(2.5)
    assert idle["idle-master-1-slaves"].met is False
    assert idle["idle-master-31-slaves"].met is None            # not in this run
    (py,) = verdicts.python_rows(_results())
    assert py.value == pytest.approx(80.0) and py.met is True


def test_part_rows_found_by_name_missing_or_failing() -> None:
    from bench import verdicts
    from bench.targets import Target

    good = types.SimpleNamespace(targets=lambda rounds: [Target("g485-115200", "g", 97.0, 95.0, True)])

    def bad(rounds: int) -> Any:
        raise RuntimeError("no bus")

    def importer(name: str) -> Any:
        if name == "bench.g485.paired":
            return good
        if name == "bench.bridge.throughput":
            return types.SimpleNamespace(targets=bad)
        raise ImportError(f"No module named {name!r}", name=name)

    rows = verdicts.part_rows(3, False, importer=importer)
    by = {t.name: t for t in rows}
    assert by["g485-115200"].met is True
    assert by["bridge-forward-115200"].met is None and "no bus" in by["bridge-forward-115200"].note
    assert by["realtime-p99-115200"].met is None and "bench.realtime" in by["realtime-p99-115200"].note
    skipped = verdicts.part_rows(3, False, skip=True, importer=importer)
    assert all(t.met is None for t in skipped)


def test_readme_section_replaced_between_markers(tmp_path: Path) -> None:
    from bench import readme, verdicts
    run = tmp_path / "bench" / "results" / "run1"
    run.mkdir(parents=True)
    res = _results()
    res.update({"date": "2026-11-26", "host": "h", "machine": "2 CPUs", "loadavg_before": "1 1 1",
                "loadavg_after": "2 2 2", "rounds": 3, "seconds": 1.5, "bauds": [115200],
                "missing": {}, "unpaced": {}, "scale": {},
                "targets": [t.as_dict() for t in verdicts.python_rows(res)]})
    res["paced"] = {"115200": {}}
    (run / "results.json").write_text(json.dumps(res))
    doc = tmp_path / "README.md"
    doc.write_text(f"# x\nbefore\n{readme.BEGIN}\nold text\n{readme.END}\nafter\n")
    readme.regenerate(doc, run, tmp_path)
    text = doc.read_text()
    assert "old text" not in text and text.startswith("# x\nbefore\n") and text.endswith("after\n")
    assert "fap_py-round-trips" in text and "1 met, 0 missed" in text
    doc.write_text("no markers\n")
    with pytest.raises(ValueError):
        readme.regenerate(doc, run, tmp_path)


def test_a_missed_cpu_ratio_names_its_floor():
    """A miss says what the floor of the cost is, computed from the same run: the fewest
    wake-ups the wire allows (1 for a client, 2 for a server) at this side's cost per wake-up."""
    from bench import verdicts

    paced = {"115200": {
        "modbus": {"client_us": {"median": 100.0}, "server_us": {"median": 100.0},
                   "client_wakeups": {"median": 10.0}, "server_wakeups": {"median": 10.0}},
        "fap-poll": {"client_us": {"median": 80.0}, "client_wakeups": {"median": 4.0},
                     "server_us": {"median": 80.0}, "server_wakeups": {"median": 2.0}}}}
    rows = {t.name: t for t in verdicts.cpu_rows({"paced": paced})}
    client, server = rows["cpu-fap-poll-115200-client"], rows["cpu-fap-poll-115200-server"]
    assert client.met is False and "floor 1 wake-up/x at ~20 µs each" in client.note
    assert "0.20x libmodbus, reachable: 3.0 wake-ups/x above it" in client.note
    assert server.met is False and "floor 2 wake-ups/x at ~40 µs each = ~80 µs/x" in server.note
    assert "below that floor" in server.note
    idle = verdicts.idle_rows({"paced": paced, "scale": {"115200": {"slaves": {"1": {
        "master_load": {"median": 0.02}, "cycles_per_s": {"median": 400.0},
        "cpu_us_per_cycle": {"median": 50.0}}}}}})
    assert "= 0.80 % at these cycles/s" in idle[0].note      # 400/s x 20 µs
