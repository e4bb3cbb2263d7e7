"""``fap web``'s HTTP API against a real sim (exec async nodes on a paced virtual bus) polled
by the C exec async master: the stream's frames are ``fap monitor --json``'s lines, the node
table agrees with the engine's counters, faults switched over HTTP show as timeouts, a capture
source's windows, downloads (pcap read back by tshark with the shipped dissector)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest
from web_helpers import (
    NODES,
    SITE,
    SSE,
    Poller,
    get,
    get_json,
    need_tool,
    node_rows,
    send,
    wait_until,
)

pytest.importorskip("aiohttp")

from fap_py.web import CaptureSource, SimSource, WebServer


@pytest.fixture()
def sim_server():
    src = SimSource(SITE)
    with WebServer(src, port=0) as srv:
        srv.start()
        yield srv, src


def test_frames_are_the_monitors_json_lines_and_table_matches_the_engine(sim_server, tmp_path):
    srv, src = sim_server
    poller = Poller(src.describe()["master_port"])
    try:
        wait_until(lambda: poller.rounds >= 10, what="10 polling rounds")
        poller.pause()
        stats = poller.master.stats
    finally:
        poller.close()
    # every request and reply of the master reached the table (the tap flushes within 50 ms)
    total = stats.tx_frames + stats.rx_frames
    wait_until(lambda: get_json(srv.url + "api/stats")["totals"]["frames"] >= total, what="all frames")
    rows = node_rows(srv.url)
    assert sum(rows[str(n)]["requests"] for n in NODES) == stats.transactions
    assert sum(rows[str(n)]["replies"] for n in NODES) == stats.replies
    assert sum(rows[str(n)]["timeouts"] for n in NODES) == stats.timeouts == 0
    sim_nodes = {n["address"]: n for n in src.sim.status()["buses"][0]["nodes"]}
    for n in NODES:
        assert rows[str(n)]["requests"] == sim_nodes[n]["requests"]
        assert rows[str(n)]["replies"] == sim_nodes[n]["replies"]
        assert rows[str(n)]["reply_p50_ms"] is not None and rows[str(n)]["live"] is True
    # the JSON lines download is `fap monitor --json` over the same tap, line for line
    status, body = get(srv.url + "api/download.jsonl")
    assert status == 200
    mon = subprocess.run([sys.executable, "-m", "fap_py", "monitor", "--protocol", "exec", "--capture",
                          src.capture, "--json"], capture_output=True, text=True, timeout=30)
    assert mon.returncode == 0, mon.stderr
    ours = body.decode().splitlines()
    assert ours == mon.stdout.splitlines()[:len(ours)] and len(ours) >= total
    # and the stream carries the same objects, each with its node and role
    sse = SSE("127.0.0.1", srv.port, "/api/stream?backlog=100000")
    try:
        got = []
        for kind, data in sse.events():
            if kind == "frames":
                got += data
            if len(got) >= len(ours):
                break
    finally:
        sse.close()
    assert [json.dumps(e["frame"], separators=(",", ":")) for e in got[:len(ours)]] == ours
    assert {e["role"] for e in got} == {"req", "ans"}
    assert {e["node"] for e in got} == {str(n) for n in NODES}


def test_fault_switched_over_http_shows_as_timeouts_and_stops(sim_server):
    srv, src = sim_server
    poller = Poller(src.describe()["master_port"], nodes=(2, 5))
    try:
        wait_until(lambda: poller.rounds >= 3)
        status, ans = send(srv.url + "api/faults", "POST", json.dumps({"kind": "no_reply", "node": 5}).encode())
        assert status == 200 and ans["ok"], ans
        fid = ans["result"]["id"]
        faults = get_json(srv.url + "api/faults")["result"]
        assert [f["id"] for f in faults["faults"]] == [fid] and "no_reply" in faults["kinds"]
        wait_until(lambda: node_rows(srv.url).get("5", {}).get("timeouts", 0) >= 3, what="timeouts of node 5")
        status, ans = send(srv.url + f"api/faults/{fid}", "DELETE")
        assert status == 200 and ans["result"][0]["id"] == fid
        poller.pause()
        before = poller.errors[5]
        # the last unanswered request counts once it is PENDING_S old (a quiet bus)
        wait_until(lambda: node_rows(srv.url)["5"]["timeouts"] == before, what="the table's timeouts")
        replies, rounds = node_rows(srv.url)["5"]["replies"], poller.rounds
        poller.resume()
        wait_until(lambda: poller.rounds >= rounds + 5)
        poller.pause()
        wait_until(lambda: node_rows(srv.url)["5"]["replies"] >= replies + 5, what="replies again")
    finally:
        poller.close()
    rows = node_rows(srv.url)
    assert rows["5"]["timeouts"] == poller.errors[5] == before   # none since the switch-off
    assert rows["5"]["active"] is True and rows["2"]["timeouts"] == 0
    # a bad request is an error answer, the sim goes on
    for body in (b"{", b"[]", json.dumps({"kind": "melt"}).encode(), json.dumps({"kind": "off", "x": 1}).encode()):
        status, ans = send(srv.url + "api/faults", "POST", body)
        assert status == 400 and ans["ok"] is False and ans["error"], (body, ans)
    status, ans = send(srv.url + "api/faults/nope", "DELETE")
    assert status == 400


def test_capture_source_windows_and_pcap_in_tshark(sim_server, tmp_path):
    srv, src = sim_server
    poller = Poller(src.describe()["master_port"], nodes=(1, 3))
    try:
        wait_until(lambda: poller.rounds >= 20)
        poller.pause()
        n = poller.master.stats.tx_frames + poller.master.stats.rx_frames
    finally:
        poller.close()
    wait_until(lambda: get_json(srv.url + "api/stats")["totals"]["frames"] >= n)
    cap = tmp_path / "bus.cap"
    cap.write_bytes(open(src.capture, "rb").read())
    with WebServer(CaptureSource(str(cap)), port=0) as cs:
        cs.start()
        assert cs.wait_source(15)
        info = get_json(cs.url + "api/info")
        assert info["seekable"] and info["span"][1] > info["span"][0] and info["decoding"] == "exec"
        whole = get_json(cs.url + "api/stats")
        assert whole["totals"]["frames"] == n and whole["source"]["done"]
        mid = (info["span"][0] + info["span"][1]) / 2
        half = get_json(cs.url + f"api/stats?t1={mid}")
        assert 0 < half["totals"]["frames"] < n
        frames = get_json(cs.url + f"api/frames?t1={mid}&limit=100000")
        assert len(frames) == half["totals"]["frames"] and all(e["frame"]["t"] <= mid for e in frames)
        status, pcap = get(cs.url + f"api/download.pcap?t1={mid}")
        assert status == 200 and pcap[:4] == b"\xd4\xc3\xb2\xa1"
        (tmp_path / "w.pcap").write_bytes(pcap)
        status, html = get(cs.url + "api/export.html")
        assert status == 200 and b"fap-export" in html and b"static/app.js" not in html
    tshark = need_tool("tshark")
    lua = tmp_path / "lua"
    subprocess.run([sys.executable, "-m", "fap_py", "monitor", "--dissectors", str(lua)], check=True,
                   capture_output=True, timeout=30)
    out = subprocess.run([tshark, "-X", f"lua_script:{lua / 'fap_monitor.lua'}", "-r", str(tmp_path / "w.pcap"),
                          "-T", "fields", "-e", "execasync.node"], capture_output=True, timeout=120)
    assert out.returncode == 0, out.stderr
    nodes = out.stdout.decode().split()
    assert len(nodes) == len(frames) and set(nodes) == {"1", "3"}


def test_a_slow_browser_gets_drops_counted_never_silent():
    """30000 frames into a ring of 500, 1000 at a time (faster than any stream can take
    them): what the browser missed comes as ``dropped`` events, and received + dropped ==
    published, in order, nothing twice."""
    from fap_py import execasync
    from fap_py.web import Source

    total = 30000

    class Burst(Source):
        kind = "test"

        def __init__(self) -> None:
            super().__init__("exec", 115200)
            import threading
            self.go = threading.Event()

        def run(self, hub, stop) -> None:
            mon = self._monitor(115200)
            wire = b"".join(execasync.encode(1 + i % 9, bytes([i & 0xFF]), 1 + i % 255) for i in range(1000))
            self.go.wait(15)
            for k in range(total // 1000):
                hub.publish(mon.feed(wire, float(k), 1e-5))

    src = Burst()
    with WebServer(src, port=0, ring=500) as srv:
        srv.start()
        sse = SSE("127.0.0.1", srv.port, "/api/stream?backlog=0")
        try:
            src.go.set()
            assert srv.wait_source(60)
            received = dropped = 0
            seqs = []
            for kind, data in sse.events():
                if kind == "frames":
                    received += len(data)
                    seqs += [e["seq"] for e in data]
                elif kind == "dropped":
                    dropped = data["total"]
                if received + dropped >= total:
                    break
        finally:
            sse.close()
        assert dropped > 0 and received + dropped == total
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
        assert get_json(srv.url + "api/stats")["totals"]["dropped_total"] == dropped


def test_a_running_sim_through_its_control_socket_and_tap(tmp_path):
    """``fap sim CONFIG --control unix:PATH`` as a process, its bus's capture as the tap: the
    same table and fault switches as an in-process sim."""
    import os
    import select
    import signal

    from fap_py.web import SimControlSource

    tap = tmp_path / "tap.cap"
    conf = tmp_path / "site.json"
    site = json.loads(json.dumps(SITE))
    site["bus"][0]["virtual"] = {"capture": str(tap)}
    conf.write_text(json.dumps(site))
    sock = f"unix:{tmp_path}/sim.sock"
    sim = subprocess.Popen([sys.executable, "-m", "fap_py", "sim", str(conf), "--control", sock, "--json"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert select.select([sim.stdout], [], [], 15)[0], "fap sim did not start"
        ready = json.loads(sim.stdout.readline())
        assert ready["event"] == "ready", ready
        src = SimControlSource(sock, str(tap))
        with WebServer(src, port=0) as srv:
            srv.start()
            info = get_json(srv.url + "api/info")
            assert info["bus"] == "field" and info["decoding"] == "exec" and info["baud"] == 115200
            poller = Poller(info["master_port"], nodes=(1, 5))
            try:
                wait_until(lambda: poller.rounds >= 3)
                status, ans = send(srv.url + "api/faults", "POST", json.dumps({"kind": "no_reply", "node": 5}).encode())
                assert status == 200, ans
                faults = get_json(srv.url + "api/faults")["result"]
                assert [f["kind"] for f in faults["faults"]] == ["no_reply"] and "bad_crc" in faults["kinds"]
                wait_until(lambda: node_rows(srv.url).get("5", {}).get("timeouts", 0) >= 2, what="timeouts")
                status, ans = send(srv.url + "api/faults/all", "DELETE")
                assert status == 200 and len(ans["result"]) == 1
                poller.pause()
                st = poller.master.stats
                wait_until(lambda: sum(n["requests"] for n in get_json(srv.url + "api/stats")["nodes"])
                           == st.transactions, what="every request in the table")
                # the last unanswered request counts once it is PENDING_S old
                wait_until(lambda: sum(n["timeouts"] for n in node_rows(srv.url).values()) == st.timeouts,
                           what="every timeout in the table")
                rows = node_rows(srv.url)
                assert rows["5"]["timeouts"] == st.timeouts == poller.errors[5] and rows["1"]["timeouts"] == 0
            finally:
                poller.close()
            status, ans = send(srv.url + "api/faults", "POST", json.dumps({"kind": "melt"}).encode())
            assert status == 400 and "melt" in ans["error"]
    finally:
        sim.send_signal(signal.SIGTERM)
        sim.communicate(timeout=15)
    assert sim.returncode == 0
    assert not os.path.exists(f"{tmp_path}/sim.sock")


def test_port_source_watches_a_live_port_receive_only():
    """A paced virtual bus: the C exec async master on port0, a C slave on port1, fap web's
    PortSource on port2 (receive-only, as fap monitor --port): the table is the master's."""
    from fap_py import RS485, RS485Mode, execasync
    from fap_py.vbus import VirtualBus
    from fap_py.web import PortSource

    line = RS485(mode=RS485Mode.NONE)
    with VirtualBus(ports=3, baud=115200) as bus, \
            execasync.Slave(bus.paths[1], 115200, node=7, handler=lambda q: b"ok" + q.data, rs485=line).start():
        with WebServer(PortSource(bus.paths[2], 115200, "exec", line), port=0) as srv:
            srv.start()
            info = get_json(srv.url + "api/info")
            assert info["kind"] == "port" and info["port"] == bus.paths[2]
            with execasync.Master(bus.paths[0], 115200, timeout=0.5, retries=0, rs485=line) as m:
                for i in range(20):
                    assert m.transact(7, bytes([i])) == b"ok" + bytes([i])
                st = m.stats
            wait_until(lambda: node_rows(srv.url).get("7", {}).get("replies", 0) == st.replies, what="replies")
            row = node_rows(srv.url)["7"]
            assert row["requests"] == st.transactions == 20 and row["timeouts"] == 0 and row["errors"] == 0
            frames = get_json(srv.url + "api/frames")
            assert all(e["frame"]["port"] is None for e in frames)      # a live port knows no sender
            status, pcap = get(srv.url + "api/download.pcap")
            assert status == 200 and len(pcap) > 24 + 40 * 16
