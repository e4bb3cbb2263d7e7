"""The monitor session (fap_py.monitor.session) on its own: what `fap monitor` and
the extcap both run, without the command line."""
from __future__ import annotations

import dataclasses
import io
import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from monitor_helpers import stream, vectors

from fap_py.errors import InvalidTypeError, InvalidValueError
from fap_py.monitor.session import Session, SessionConfig, protocol_choice, protocol_choices
from fap_py.monitor.sources import LivePort
from fap_py.port import PortStats
from fap_py.vbus import VirtualBus

WAIT_S = 20.0


def test_choices_and_aliases_come_from_the_protocol_table() -> None:
    from fap_py import _protocols

    assert protocol_choices() == ("auto",) + _protocols.names()
    assert protocol_choice("execasync") == "exec" == protocol_choice("EXEC")
    assert SessionConfig(protocol="execasync").protocol == "exec"
    with pytest.raises(InvalidValueError, match="choose from auto, fap"):
        protocol_choice("modbus")


def test_a_session_decodes_a_file_and_publishes_frozen_stats(tmp_path: Path) -> None:
    raw = tmp_path / "exec.bin"
    raw.write_bytes(stream("exec"))
    out = io.StringIO()
    s = Session(SessionConfig(protocol="auto", raw_file=str(raw), as_json=True, quiet=True), out)
    assert s.run() == 0
    good = sum(v.ok for v in vectors("exec"))
    recs = [json.loads(line) for line in out.getvalue().splitlines()]
    assert s.protocol == "exec"
    assert s.stats.frames == good == sum(r["ok"] for r in recs)
    assert s.stats.bytes == raw.stat().st_size
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.stats.frames = 0
    with pytest.raises(TypeError):
        s.stats.errors["crc"] = 0


def test_config_refuses_two_inputs_and_bad_values(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match="one input"):
        SessionConfig(raw_file="a", capture_file="b")
    with pytest.raises(InvalidTypeError):
        SessionConfig(as_json=1)
    with pytest.raises(InvalidValueError):
        SessionConfig(idle_s=-1)
    with pytest.raises(InvalidTypeError):
        Session(SessionConfig(), out="stdout")


def test_live_port_reads_through_fap_py_port() -> None:
    """LivePort is a fap_py.port.Port: its counters are the port layer's."""
    data = stream("mikroc")
    with VirtualBus(ports=2) as bus, LivePort(bus.paths[1], 115200) as live:
        assert isinstance(live.stats, PortStats) and live.stats.rx_bytes == 0
        fd = os.open(bus.paths[0], os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, data)
        finally:
            os.close(fd)
        got = b""
        deadline = time.monotonic() + WAIT_S
        for chunk in live.chunks(lambda: None, None, lambda: time.monotonic() > deadline
                                 or len(got) >= len(data)):
            if chunk is not None:
                got += chunk.data
        assert got == data
        assert live.stats.rx_bytes == len(data)


def test_the_extcap_runs_the_session_without_the_command_line(tmp_path: Path) -> None:
    """A capture whose port cannot open: one line on stderr, exit 3 (as `fap`), and
    fap_py.cli never imported (the extcap is a library room)."""
    code = textwrap.dedent(f"""
        import sys
        from fap_py.monitor import extcap
        rc = extcap.main(["--capture", "--fifo", {str(tmp_path / 'f')!r}, "--port",
                          {str(tmp_path / 'no-such-tty')!r}, "--protocol", "execasync"])
        print(rc, "fap_py.cli" in sys.modules, "fap_py.commands" in sys.modules)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=WAIT_S, cwd=tmp_path)
    assert r.stdout.split() == ["3", "False", "False"], (r.stdout, r.stderr)
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("fap: error: "), r.stderr
    assert "no-such-tty" in r.stderr
