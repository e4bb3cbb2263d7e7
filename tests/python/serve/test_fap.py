"""`fap serve --protocol fap --slaves IDS`: the daemon's FAP master polls the slaves;
fap_py.Master on a fapd:// URL sends to a slave through it and receives what slaves send."""
from __future__ import annotations

import asyncio
import json
import subprocess

import pytest
from serve_helpers import fap_cmd, fap_echo, start_daemon

from fap_py import Master, Slave
from fap_py.errors import NotMasterError, UnknownSlaveError
from fap_py.rs485 import RS485, RS485Mode
from fap_py.serve import Connection
from fap_py.vbus import VirtualBus


def test_fap_master_on_a_daemon_url(tmp_path):
    with VirtualBus(ports=2, baud=115200) as bus, fap_echo(bus.paths[1]):
        d = start_daemon(str(tmp_path), bus.paths[0], "--slaves", "3", protocol="fap")
        try:
            with Master(d.url, slaves=[3]) as m:
                assert type(m).__name__ == "DaemonFapMaster"
                m.wait_active([3], timeout=10)
                assert m.active_slaves == [3] and m.is_active(3)
                m.send(b"abc", 3)
                msg = m.recv(timeout=10)
                assert (msg.source, msg.data) == (3, b"cba")
                m.send(b"xy", 3)

                async def arecv():
                    return await m.arecv(timeout=10)
                msg = asyncio.run(arecv())
                assert (msg.source, msg.data) == (3, b"yx")
                m.flush(5)
                assert m.stats.frames_tx > 0
                with pytest.raises(NotMasterError):
                    m.add_slave(4)
            with pytest.raises(UnknownSlaveError):
                Master(d.url, slaves=[3, 7])
            with Connection(d.url) as tap:                # the monitor's tap: the engine's frames
                tap.call("monitor")
                dirs = set()
                while dirs != {"tx", "rx"}:
                    ev = tap.next_event(30)                # bounded; long for a loaded machine
                    assert ev is not None and ev["event"] == "frame"
                    dirs.add(ev["dir"])
            # the CLI sends and exits once it is sent (--wait 30: the default 5 s once ran out
            # under a hog beside a CI run); the slave's answer reaches every client of the
            # daemon, so a listener that stays sees it (the CLI may have left before it came)
            with Master(d.url, slaves=[3]) as listener:
                r = subprocess.run(fap_cmd("fap", "master", "--port", d.url, "--slaves", "3", "0102",
                                           "--wait", "30", "--json"), capture_output=True, text=True,
                                   timeout=90)
                assert r.returncode == 0, r.stderr
                objs = [json.loads(x) for x in r.stdout.splitlines()]
                assert {"event": "sent", "to": 3, "data": "0102"} in objs
                for _ in range(10):
                    msg = listener.recv(timeout=30)
                    if msg.data == b"\x02\x01":
                        break
                assert (msg.source, msg.data) == (3, b"\x02\x01")
            assert d.status()["totals"]["transactions"] >= 1
        finally:
            d.stop()


def test_fap_events_carry_the_slave_not_a_request_id(tmp_path):
    """An engine event names its slave as `slave`: a field `id` is what a client matches its
    answers by, and an event that carried the slave's ID there was once taken for the answer
    to request 3 (a DaemonFapMaster call then failed with 'bad error object None')."""
    with VirtualBus(ports=2, baud=115200) as bus:
        d = start_daemon(str(tmp_path), bus.paths[0], "--slaves", "3", protocol="fap")
        try:
            with Connection(d.url) as c:
                with Slave(bus.paths[1], id=3, rs485=RS485(mode=RS485Mode.NONE)):
                    ev = None
                    for _ in range(100):
                        ev = c.next_event(10)
                        assert ev is not None
                        if ev.get("event") == "fap_event":
                            break
                    assert ev is not None and ev["event"] == "fap_event"
                    assert "id" not in ev and ev["slave"] == 3
                    for _ in range(20):    # calls stay matched to their own answers meanwhile
                        assert c.call("slaves")["slaves"] == [3]
        finally:
            d.stop()
