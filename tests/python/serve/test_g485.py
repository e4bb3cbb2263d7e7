"""`fap serve --protocol g485`: the G485 session on the daemon, fap_py.g485.G485Master and
`fap g485 ...` on a fapd:// URL, against the project's device simulator."""
from __future__ import annotations

import asyncio
import json
import subprocess

import pytest
from serve_helpers import fap_cmd, start_daemon

from fap_py.g485 import G485Master, NoResponseError
from fap_py.g485.aio import AsyncG485Master
from fap_py.g485.device import SimDevice
from fap_py.g485.simulator import Simulator
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus


def test_g485_master_on_a_daemon_url(tmp_path):
    with VirtualBus(ports=2, baud=115200) as bus, \
            Simulator(bus.paths[1], [SimDevice(3)], rs485=RS485(mode=RS485Mode.NONE)):
        d = start_daemon(str(tmp_path), bus.paths[0], "--timeout", "0.3", "--retries", "1",
                         protocol="g485")
        try:
            with G485Master(d.url) as m:
                assert type(m).__name__ == "DaemonG485Master"
                m.write(3, 10, b"\x2a")
                assert m.read(3, 10) == b"\x2a"
                assert m.read_register(3, 7) == 3                  # register 7: its ID
                assert isinstance(m.handshake(3), int)
                assert m.error_word(3) == 0
                with pytest.raises(NoResponseError):
                    m.read(9, 1, timeout=0.02, retries=0)
                assert m.scan(range(2, 5), timeout=0.2) == [3]
                assert m.stats.transactions >= 4 and m.stats.no_response >= 1

            async def aread():
                async with AsyncG485Master(d.url) as am:      # its worker thread drives the client
                    return await asyncio.gather(am.read(3, 10), am.handshake(3))
            data, check = asyncio.run(aread())
            assert data == b"\x2a" and isinstance(check, int)
            r = subprocess.run(fap_cmd("g485", "read", "--port", d.url, "--address", "3",
                                       "--register", "10", "--json"),
                               capture_output=True, text=True, timeout=30)
            assert r.returncode == 0, r.stderr
            objs = [json.loads(x) for x in r.stdout.splitlines()]
            assert any(o.get("data") in ("2a", [42]) or o.get("values") == [42] for o in objs), objs
            st = d.status()
            assert st["daemon"]["protocol"] == "g485" and st["totals"]["errors"] >= 1
        finally:
            d.stop()
