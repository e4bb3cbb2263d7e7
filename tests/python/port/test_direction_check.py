"""``fap ports --check``: the release of the direction line timed against the
echo of a test pattern, on the virtual bus with echo (each port hears its
own bytes, as a transceiver with RX during TX). A pty has no transmitter,
so ``tcdrain`` returns at once: on a paced bus the release comes a whole
frame before the last echoed byte, and the check must say so."""
from __future__ import annotations

import json

import pytest

from fap_py.direction_check import PATTERN, judge, measure
from fap_py.port import Port
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus

NONE = RS485(mode=RS485Mode.NONE)


def test_judge_verdicts() -> None:
    ok = judge("d", RS485Mode.SOFT_RTS, 2, 2, 0, (100, 50), False)
    assert ok.release_us == 75 and not ok.warnings and ok.recommend == "soft"
    early = judge("d", RS485Mode.SOFT_RTS, 1, 1, 0, (-400,), False)
    assert "400 us before its last byte" in early.warnings[0]
    silent = judge("d", RS485Mode.NONE, 1, 0, 0, (), True)
    assert silent.release_us is None and "no echo" in silent.warnings[0]
    assert silent.recommend == "kernel"
    hit = judge("d", RS485Mode.GPIO, 1, 1, 1, (9,), False)
    assert hit.collisions == 1 and hit.recommend == "gpio" and "differ" in hit.warnings[-1]


def test_measure_on_an_echoing_bus() -> None:
    with VirtualBus(ports=2, echo=True) as bus:
        res = measure(bus.paths[0], 115200, NONE, rounds=3)
    assert res.echoed == 3 and res.collisions == 0 and len(res.margins_us) == 3
    assert res.mode == "none" and res.recommend == "none"


def test_check_sees_an_early_release_on_a_paced_bus(capsys: pytest.CaptureFixture) -> None:
    from fap_py.cli import main

    wire_us = len(PATTERN) * 10 * 1_000_000 // 9600   # the pattern's time on the paced wire
    with VirtualBus(ports=2, echo=True, baud=9600) as bus:
        code = main(["ports", "--check", bus.paths[0], "--baud", "9600", "--rounds", "2", "--json"])
        row = json.loads(capsys.readouterr().out.splitlines()[-1])
        assert code == 1 and row["event"] == "check" and row["echoed"] == 2
        assert max(row["margins_us"]) < -wire_us // 2   # released a frame before the echo ended
        assert row["mode"] == "none" and "tcdrain does not cover" in row["warnings"][0]
        assert main(["ports", "--check", bus.paths[0], "--baud", "9600", "--rounds", "1"]) == 1
        assert "before the last echoed byte" in capsys.readouterr().out


def test_check_on_a_silent_line_and_a_held_port(capsys: pytest.CaptureFixture) -> None:
    from fap_py.cli import main

    with VirtualBus(ports=2, echo=False) as bus:
        assert main(["ports", "--check", bus.paths[0], "--rounds", "1"]) == 1
        assert "no echo" in capsys.readouterr().out
        with Port(bus.paths[0], 115200, NONE):
            assert main(["ports", "--check", bus.paths[0]]) == 1
        assert "busy" in capsys.readouterr().err
