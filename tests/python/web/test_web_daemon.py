"""``fap web --port fapd://...``: a bus ``fap serve`` owns. The frames come from the daemon's
passive tap (the monitor's decoders, as for a port), the clients table from its status: a
real daemon on a paced virtual bus with a C exec async slave, a client process's transactions
through it, the page in headless Chromium."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest
from web_helpers import get, get_json, node_rows, wait_until

pytest.importorskip("aiohttp")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "serve"))
from serve_helpers import start_daemon

from fap_py import execasync
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus
from fap_py.web import DaemonSource, NoClientsError, SimSource, WebServer

LINE = RS485(mode=RS485Mode.NONE)


@pytest.fixture()
def daemon(tmp_path):
    with VirtualBus(ports=2, baud=115200) as bus, \
            execasync.Slave(bus.paths[1], node=5, handler=lambda r: r.data, rs485=LINE) as slave:
        slave.start()
        d = start_daemon(str(tmp_path), bus.paths[0])
        try:
            yield d
        finally:
            d.stop()


def test_daemon_source_frames_and_clients(daemon):
    src = DaemonSource(daemon.url)
    with WebServer(src, port=0) as srv:
        srv.start()
        info = get_json(srv.url + "api/info")
        assert (info["kind"], info["clients"], info["faults"], info["baud"]) == ("daemon", True, False, 115200)
        with execasync.Master(daemon.url + "?name=hmi&weight=3") as m:
            got = [m.transact(5, bytes([i])) for i in range(20)]
        assert got == [bytes([i]) for i in range(20)]
        # every request and reply the daemon moved reached the node table through the tap
        wait_until(lambda: node_rows(srv.url).get("5", {}).get("replies", 0) >= 20, what="20 replies")
        row = node_rows(srv.url)["5"]
        assert row["requests"] == 20 and row["timeouts"] == 0
        ans = get_json(srv.url + "api/clients")
        assert ans["ok"]
        st = ans["result"]
        assert st["daemon"]["protocol"] == "exec" and st["totals"]["transactions"] == 20
        # the page's own tap and status calls are not listed; the client that left is gone
        assert all(c["name"] not in ("monitor", "status") for c in st["clients"])
        with execasync.Master(daemon.url + "?name=logger&weight=2") as m2:
            m2.transact(5, b"x")
            clients = wait_until(lambda: [c for c in get_json(srv.url + "api/clients")["result"]["clients"]
                                          if c["name"] == "logger"], what="the logger client")
            assert clients[0]["weight"] == 2 and clients[0]["transactions"] == 1
            assert 0 < clients[0]["share"] < 0.2     # of the wire time since the daemon started: 1 of 21


def test_clients_refused_where_there_is_no_daemon(daemon, tmp_path):
    from web_helpers import SITE

    with WebServer(SimSource(SITE), port=0) as srv:
        srv.start()
        status, body = get(srv.url + "api/clients")
        assert status == 400 and b"no clients" in body
    with pytest.raises(NoClientsError):
        SimSource(SITE).clients()
    from fap_py.errors import FapError
    with pytest.raises(FapError, match="fapd:// URL"):
        DaemonSource("/dev/ttyS0")
