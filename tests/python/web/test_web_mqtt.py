"""``fap web --mqtt``: a real bridge (fap_py.bridge.Bridge) polling a C exec async slave on a
virtual bus, publishing to a real mosquitto; fap web subscribes with the bridge's own config
and shows its publications and its per-node counters. Skips without mosquitto unless CI."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from web_helpers import SSE, get_json, need_tool, wait_until

pytest.importorskip("aiohttp")
pytest.importorskip("paho.mqtt.client")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bridge"))
from mosquitto import Mosquitto

from fap_py.web import MqttSource, WebServer


def test_a_bridges_topics(tmp_path):
    from fap_py.bridge import Bridge
    from fap_py.bridge.config import load
    from fap_py.execasync import Slave
    from fap_py.vbus import VirtualBus

    need_tool("mosquitto")
    with Mosquitto(str(tmp_path / "broker")) as broker, VirtualBus(2) as bus, \
            Slave(bus.paths[1], node=5, handler=lambda req: b"re:" + req.data).start():
        conf = tmp_path / "bridge.toml"
        conf.write_text(f"""
[broker]
url = "mqtt://127.0.0.1:{broker.port}"
reconnect_min = 0.05
reconnect_max = 0.5
[bridge]
host = "test"
state_dir = "{tmp_path}"
stats_interval = 0.2
[[bus]]
name = "ex"
port = "{bus.paths[0]}"
protocol = "exec"
nodes = [5]
poll_data = "7071"
poll_interval = 0.05
timeout = 0.2
retries = 0
""")
        src = MqttSource(str(conf))
        with WebServer(src, port=0) as srv:
            srv.start()
            assert src.connected.wait(10)
            with Bridge(load(str(conf))) as bridge:
                assert bridge.wait_connected(10)
                rows = wait_until(lambda: [n for n in get_json(srv.url + "api/stats")["nodes"]
                                           if n["node"] == "5" and n["replies"] >= 5], what="node 5's counters")
                assert rows[0]["timeouts"] == 0 and rows[0]["active"] is True
            info = get_json(srv.url + "api/info")
            assert info["kind"] == "mqtt" and info["bus"] == "ex" and info["topics"] == "fap/ex/#"
            sse = SSE("127.0.0.1", srv.port, "/api/stream?backlog=100000")
            try:
                got = []
                for kind, data in sse.events():
                    if kind == "frames":
                        got += data
                    if {"rx", "state", "stats"} <= {e["frame"]["event"] for e in got}:
                        break
            finally:
                sse.close()
            rx = [e for e in got if e["frame"]["event"] == "rx"]
            assert rx and rx[0]["node"] == "5" and rx[0]["role"] == "ans"
            assert rx[0]["frame"]["payload"]["data"] == b"re:pq".hex() and rx[0]["frame"]["topic"] == "fap/ex/5/rx"
            status = get_json(srv.url + "api/stats")
            assert status["totals"]["frames"] >= len(got) and src.refused == 0
            # a pcap of messages holds no frame (they are not wire bytes); the JSON lines hold them
            from web_helpers import get

            st, body = get(srv.url + "api/download.jsonl")
            assert st == 200 and json.loads(body.splitlines()[0])["protocol"] == "mqtt"
