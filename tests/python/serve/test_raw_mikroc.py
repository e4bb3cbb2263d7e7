"""`fap serve --protocol raw` (request bytes + a reply rule) and `--protocol mikroc`
(send + reply through the C engine; fap_py.mikroc.Master on a fapd:// URL)."""
from __future__ import annotations

import asyncio
import json
import subprocess

import pytest
from serve_helpers import fap_cmd, mikroc_echo, start_daemon

from fap_py import mikroc
from fap_py.errors import FapTimeoutError
from fap_py.execasync import RS485, Decoder, RS485Mode, encode
from fap_py.serve import Connection
from fap_py.vbus import VirtualBus

LINE = RS485(mode=RS485Mode.NONE)


def test_raw_reply_rules(vbus, tmp_path):
    d = start_daemon(str(tmp_path), vbus.master_port, protocol="raw")
    try:
        with Connection(d.url, protocol="raw") as c:
            req = encode(5, b"abc", seq=1)
            for rule in ({"idle": 0.01}, {"length": len(req)}, {"terminator": req[-4:-2].hex()}):
                got = bytes.fromhex(c.call("transact", data=req.hex(), timeout=0.5, **rule)["data"])
                frames = Decoder().feed(got)
                if "terminator" in rule:         # DLE ETX: the frame up to its CRC
                    assert got == req[:-2]
                else:
                    assert [(f.node, f.data) for f in frames] == [(5, b"abc")]
            with pytest.raises(FapTimeoutError):
                c.call("transact", data=encode(9, b"x", seq=1).hex(), length=4, timeout=0.05)
            assert c.call("send", data="00")["ok"]
        assert d.status()["totals"]["errors"] == 1
    finally:
        d.stop()


def test_mikroc_master_on_a_daemon_url(tmp_path):
    with VirtualBus(ports=2, baud=19200) as bus, mikroc_echo(bus.paths[1]):
        d = start_daemon(str(tmp_path), bus.paths[0], "--baud", "19200", "--timeout", "0.3",
                         protocol="mikroc")
        try:
            with mikroc.Master(d.url) as m:
                assert isinstance(m, mikroc.DaemonMaster)
                r = m.request(0x12, b"\x01\x02\x03", timeout=0.5)
                assert (r.address, r.data) == (0x12, b"\x03\x02\x01")
                m.send(0x12, b"\x07")
                assert m.receive(timeout=0.5).data == b"\x07"
                with pytest.raises(FapTimeoutError):
                    m.request(0x33, b"\x00", timeout=0.05)
                with pytest.raises(FapTimeoutError):
                    m.receive(timeout=0.05)          # nothing of ours outstanding
                assert m.stats.frames == 2

                async def many():
                    return await asyncio.gather(*[m.arequest(0x12, bytes([i, 9])) for i in range(4)])
                assert [x.data for x in asyncio.run(many())] == [bytes([9, i]) for i in range(4)]
            r = subprocess.run(fap_cmd("mikroc", "master", "--port", d.url, "--address", "18",
                                       "0102", "--json"), capture_output=True, text=True, timeout=30)
            assert r.returncode == 0, r.stderr
            assert [json.loads(x)["data"] for x in r.stdout.splitlines()
                    if json.loads(x)["event"] == "reply"] == ["0201"]
        finally:
            d.stop()
