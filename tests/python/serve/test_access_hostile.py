"""Access and hostile clients: the token is checked before any bus traffic, another
major version is refused with a clear message, garbage / oversized / half-sent
messages, connection floods and a client that never reads are cut off while a
well-behaved client keeps using the bus."""
from __future__ import annotations

import os
import struct
import subprocess

import pytest
from serve_helpers import closed_by_peer, fap_cmd, raw_connect, recv_msg, send_msg, start_daemon

from fap_py.execasync import Master
from fap_py.serve import DaemonRefusedError


def _hello(**kw):
    return {"op": "hello", "version": [1, 0], **kw}


def test_token_is_checked_before_any_bus_traffic(vbus, tmp_path, monkeypatch):
    tok = tmp_path / "token"
    tok.write_text("s3cret\n")
    d = start_daemon(str(tmp_path), vbus.master_port, "--token-file", str(tok))
    try:
        monkeypatch.delenv("FAP_SERVE_TOKEN", raising=False)
        with pytest.raises(DaemonRefusedError, match="token"):
            Master(d.url)
        with pytest.raises(DaemonRefusedError, match="token"):
            Master(d.url + "?token=wrong")
        assert vbus.spy_frames() == []                   # nothing reached the bus
        r = subprocess.run(fap_cmd("exec", "master", "--port", d.url, "--node", "5", "01"),
                           capture_output=True, text=True, timeout=30)
        assert r.returncode == 3 and "token" in r.stderr
        with Master(d.url + "?token=s3cret") as m:
            assert m.transact(5, b"a") == b"a"
        monkeypatch.setenv("FAP_SERVE_TOKEN", "s3cret")
        with Master(d.url) as m:
            assert m.transact(5, b"b") == b"b"
        assert d.status()["totals"]["refused"] == 3
    finally:
        d.stop()


def test_tcp_beyond_loopback_needs_a_token(vbus, tmp_path):
    r = subprocess.run(fap_cmd("serve", "--protocol", "exec", "--port", vbus.master_port,
                               "--rs485", "none", "--listen", "tcp://0.0.0.0:0", "--lock-dir",
                               str(tmp_path)), capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "--token-file" in r.stderr


def test_tcp_loopback_listener(vbus, tmp_path):
    d = start_daemon(str(tmp_path), vbus.master_port, "--listen", "tcp://127.0.0.1:0")
    try:
        tcp = [u for u in d.ready["listen"] if not u.startswith("fapd:///")]
        assert len(tcp) == 1 and not tcp[0].endswith(":0")
        with Master(tcp[0], timeout=0.2) as m:
            assert m.transact(5, b"tcp") == b"tcp"
    finally:
        d.stop()


def test_another_major_version_is_refused_clearly(served):
    s = raw_connect(served.sock)
    send_msg(s, _hello(version=[2, 0]))
    msg = recv_msg(s)
    assert msg["op"] == "refused" and "major" in msg["error"]["message"]
    assert recv_msg(s) is None
    s.close()


@pytest.mark.parametrize("payload", [
    struct.pack(">I", 0xFFFFFFFF) + b"x",            # oversized length
    struct.pack(">I", 0),                            # empty message
    struct.pack(">I", 5) + b"\xff\xfe{[}",            # not UTF-8 JSON
    struct.pack(">I", 2) + b"[]",                     # JSON, not an object
], ids=["oversized", "empty", "garbage", "not-object"])
def test_garbage_is_cut_off(served, payload):
    s = raw_connect(served.sock)
    send_msg(s, _hello())
    assert recv_msg(s)["op"] == "welcome"
    s.sendall(payload)
    assert closed_by_peer(s)
    s.close()
    with Master(served.url, timeout=0.2) as m:       # the bus goes on
        assert m.transact(5, b"ok") == b"ok"


def test_half_sent_and_silent_clients_are_cut_off_without_stalling_the_bus(vbus, tmp_path):
    d = start_daemon(str(tmp_path), vbus.master_port, "--client-timeout", "0.5")
    try:
        silent = raw_connect(d.sock)                  # never says hello
        half = raw_connect(d.sock)
        send_msg(half, _hello())
        assert recv_msg(half)["op"] == "welcome"
        half.sendall(struct.pack(">I", 100) + b'{"op":')   # and never the rest
        with Master(d.url, timeout=0.2) as m:
            assert [m.transact(5, bytes([i])) for i in range(20)] == [bytes([i]) for i in range(20)]
        assert closed_by_peer(silent) and closed_by_peer(half)
        assert d.status()["totals"]["cut_off"] >= 2
    finally:
        d.stop()


def test_a_connection_flood_is_refused_beyond_max_clients(vbus, tmp_path):
    d = start_daemon(str(tmp_path), vbus.master_port, "--max-clients", "4")
    socks = []
    try:
        with Master(d.url, timeout=0.2) as m:
            for _ in range(3):
                s = raw_connect(d.sock)
                send_msg(s, _hello())
                assert recv_msg(s)["op"] == "welcome"
                socks.append(s)
            extra = [raw_connect(d.sock) for _ in range(10)]
            for s in extra:
                msg = recv_msg(s)
                assert msg["op"] == "refused" and "too many clients" in msg["error"]["message"]
                s.close()
            assert m.transact(5, b"still") == b"still"
        st = d.status()
        assert st["totals"]["refused"] == 10
    finally:
        for s in socks:
            s.close()
        d.stop()


def test_a_client_that_never_reads_is_cut_off(vbus, tmp_path):
    d = start_daemon(str(tmp_path), vbus.master_port, "--write-limit", "65536")
    try:
        s = raw_connect(d.sock)
        send_msg(s, _hello())
        assert recv_msg(s)["op"] == "welcome"
        s.setsockopt(__import__("socket").SOL_SOCKET, __import__("socket").SO_RCVBUF, 4096)
        cut = False
        try:
            for i in range(20000):                    # status answers pile up unread
                send_msg(s, {"op": "status", "id": i})
                if i % 500 == 0 and d.status()["totals"]["cut_off"]:
                    cut = True
                    break
        except (BrokenPipeError, ConnectionResetError):
            cut = True
        assert cut or d.wait_for(lambda st: st["totals"]["cut_off"] == 1)
        with Master(d.url, timeout=0.2) as m:
            assert m.transact(5, b"ok") == b"ok"
        s.close()
    finally:
        d.stop()


def test_bad_requests_get_an_error_and_the_connection_stays(served):
    s = raw_connect(served.sock)
    send_msg(s, _hello())
    assert recv_msg(s)["op"] == "welcome"
    send_msg(s, {"op": "transact", "id": 1, "node": 999, "data": "00"})
    send_msg(s, {"op": "transact", "id": 2, "node": 5, "data": "zz"})
    send_msg(s, {"op": "frobnicate", "id": 3})
    send_msg(s, {"op": "transact", "id": 4, "node": 5, "data": "0a0b"})
    got = {m["id"]: m for m in (recv_msg(s) for _ in range(4))}
    assert [got[i]["ok"] for i in (1, 2, 3, 4)] == [False, False, False, True]
    assert got[1]["error"]["type"] == "ProtocolError" and got[4]["data"] == "0a0b"
    s.close()


def test_a_full_queue_is_a_clear_error(vbus, tmp_path):
    vbus.late_gate.clear()                             # node 6 holds the bus
    d = start_daemon(str(tmp_path), vbus.master_port, "--queue", "2")
    try:
        s = raw_connect(d.sock)
        send_msg(s, _hello())
        assert recv_msg(s)["op"] == "welcome"
        send_msg(s, {"op": "transact", "id": 0, "node": 6, "data": "00", "timeout": 5, "retries": 0})
        assert vbus.hold.wait(10)                       # on the wire: the queue is free again
        for i in (1, 2, 3):
            send_msg(s, {"op": "transact", "id": i, "node": 5, "data": "01"})
        msg = recv_msg(s)
        assert msg["id"] == 3 and msg["error"]["type"] == "ClientQueueFullError"
        assert "queue full" in msg["error"]["message"]
        vbus.late_gate.set()
        assert sorted(recv_msg(s)["id"] for _ in range(3)) == [0, 1, 2]
        assert d.status()["totals"]["queue_full"] == 1
        s.close()
    finally:
        d.stop()


def test_dead_daemon_and_bad_url_exit_3(tmp_path):
    for port in (f"fapd://{tmp_path}/none.sock", "fapd://127.0.0.1:1", "fapd://nohost",
                 "fapd:///x.sock?bogus=1"):
        r = subprocess.run(fap_cmd("exec", "master", "--port", port, "--node", "5", "01"),
                           capture_output=True, text=True, timeout=30)
        assert r.returncode == 3, (port, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert os.path.exists(str(tmp_path))
