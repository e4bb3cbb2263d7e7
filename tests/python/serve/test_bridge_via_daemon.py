"""The bridge on a daemon's bus: tests/python/bridge's exec master test (test_bridge_protocols
.py::test_execasync_master) with the bus port a fapd:// URL. The bridge opens its exec
master through fap_py.execasync.Master, which takes the URL: nothing in the bridge knows."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

BRIDGE_TESTS = Path(__file__).resolve().parents[1] / "bridge"
sys.path.insert(0, str(BRIDGE_TESTS))
from bridge_helpers import WAIT, Observer, bridge_config, need  # noqa: E402
from mosquitto import MOSQUITTO, Mosquitto  # noqa: E402
from serve_helpers import start_daemon  # noqa: E402


@pytest.fixture
def mqtt():
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        mqtt = None
    need("paho-mqtt (pip install 'fap_py[bridge]')", mqtt is not None)
    return mqtt


def test_bridge_exec_master_through_the_daemon(mqtt, vbus, tmp_path):
    from fap_py.bridge import Bridge

    need("mosquitto", MOSQUITTO is not None)
    d = start_daemon(str(tmp_path), vbus.master_port)
    try:
        with Mosquitto(str(tmp_path / "broker")) as broker:
            obs = Observer(mqtt, broker.port, "fap/#")
            try:
                buses = [{"name": "ex", "port": d.url, "protocol": "exec", "nodes": [5],
                          "poll_data": "7071", "poll_interval": 0.05, "timeout": 0.2, "retries": 1}]
                with Bridge(bridge_config(broker.port, str(tmp_path / "state"), buses)) as bridge:
                    assert bridge.wait_connected(WAIT)
                    obs.wait_for("fap/ex/5/rx", lambda m: m["data"] == b"pq".hex())   # node 5 echoes
                    obs.publish("fap/ex/5/tx", {"id": "e1", "data": "0102"})
                    (reply,) = obs.wait_for("fap/ex/5/rx", lambda m: m.get("reply_to") == "e1")
                    assert reply["data"] == "0102"
                    obs.publish("fap/ex/7/tx", {"id": "e2", "data": "00"})   # nobody is node 7
                    obs.wait_for("fap/ex/7/error", lambda m: m["id"] == "e2")
                    st = d.status()
                    assert [c["name"] for c in st["clients"] if c["name"] != "status"] == ["exec master"]
                assert d.status()["totals"]["transactions"] >= 2          # polls and the tx
            finally:
                obs.close()
    finally:
        d.stop()
