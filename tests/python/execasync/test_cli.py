"""``fap exec``: encode/decode, and poll/slave against each other on a virtual bus."""
from __future__ import annotations

import threading

import pytest

from fap_py.cli import main
from fap_py.execasync import RS485, Master, RS485Mode, Slave
from fap_py.vbus import VirtualBus


def test_encode_decode(capsys: pytest.CaptureFixture) -> None:
    assert main(["exec", "encode", "--node", "5", "--seq", "1", "414243"]) == 0
    assert capsys.readouterr().out.strip() == "100205014142431003b9ec"
    assert main(["exec", "decode", "100205014142431003b9ec"]) == 0
    assert capsys.readouterr().out.strip() == "node 5 seq 1 GOOD data 414243"
    assert main(["exec", "decode", "100205014142431003b9ed"]) == 1
    assert "BAD_CRC" in capsys.readouterr().out


def test_poll_a_slave(capsys: pytest.CaptureFixture) -> None:
    with VirtualBus(ports=2) as bus, \
            Slave(bus.paths[1], node=7, handler=lambda r: r.data[::-1],
                  rs485=RS485(mode=RS485Mode.NONE)).start():
        rc = main(["exec", "poll", "--port", bus.paths[0], "--rs485", "none",
                   "--node", "7", "--count", "2", "--interval", "0", "0102"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "node 7 seq 0: 02 01" in out and "node 7 seq 1: 02 01" in out


def test_slave_command_answers(capsys: pytest.CaptureFixture) -> None:
    with VirtualBus(ports=2) as bus:
        result = []
        t = threading.Thread(target=lambda: result.append(main(
            ["exec", "slave", "--port", bus.paths[1], "--rs485", "none", "--node", "3",
             "--reply", "c0ffee", "--max-requests", "1"])))
        t.start()
        # the slave may open its port after our first attempt: short attempts, many
        with Master(bus.paths[0], timeout=0.2, retries=10,
                    rs485=RS485(mode=RS485Mode.NONE)) as master:
            assert master.transact(3, b"\x01") == b"\xc0\xff\xee"
        t.join(5)
    assert result == [0]
    assert "seq 0: 01" in capsys.readouterr().out
