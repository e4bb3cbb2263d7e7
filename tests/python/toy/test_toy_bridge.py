"""The bridge picks up the toy protocol by name (toyproto/bridge/protocols/toy.py), with no
edit to fap_py: its config keys are checked by the plug-in (node range from the toy's table
row), and a bridge on a virtual bus polls a toy slave and forwards its replies to a real
mosquitto; a tx reaches the slave and its reply comes back."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from toyproto import binding

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "bridge"))
from bridge_helpers import WAIT, Observer, bridge_config, need  # noqa: E402
from mosquitto import MOSQUITTO, Mosquitto  # noqa: E402

from fap_py.bridge.config import BridgeConfigError, bus_from_dict  # noqa: E402


def test_the_toy_plugin_checks_its_keys(toy_protocol):
    bus = bus_from_dict({"name": "t", "port": "/dev/null", "protocol": "toy", "nodes": [2, 3], "poll_data": "01"})
    assert (bus.protocol, bus.options.nodes, bus.options.poll_data) == ("toy", (2, 3), b"\x01")
    assert bus.baud == toy_protocol.default_baud and bus.timeout == 0.2
    with pytest.raises(BridgeConfigError, match=r"nodes must be in 1\.\.9"):   # the toy's NODE_MAX
        bus_from_dict({"name": "t", "port": "/dev/null", "protocol": "toy", "nodes": [binding.NODE_MAX + 1]})
    with pytest.raises(BridgeConfigError, match="role"):
        bus_from_dict({"name": "t", "port": "/dev/null", "protocol": "toy", "role": "slave"})


def test_fap_bridge_check_sees_the_toy_in_a_child(tmp_path, toy_env):
    conf = tmp_path / "bridge.toml"
    conf.write_text("[broker]\nurl = 'mqtt://127.0.0.1'\n[[bus]]\nname = 't'\nport = '/dev/null'\n"
                    "protocol = 'toy'\nnodes = [3]\n")
    res = subprocess.run([sys.executable, "-m", "fap_py", "bridge", "--config", str(conf), "--check"],
                         env=toy_env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert res.returncode == 0 and "ok: 1 bus" in res.stdout, res.stderr


def test_the_bridge_forwards_a_toy_slave(tmp_path, toy_protocol):
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        mqtt = None
    need("paho-mqtt (pip install 'fap_py[bridge]')", mqtt is not None)
    need("mosquitto", MOSQUITTO is not None)
    from fap_py.bridge import Bridge
    from fap_py.vbus import VirtualBus

    with Mosquitto(str(tmp_path / "broker")) as broker, VirtualBus(ports=2) as vbus, \
            binding.Slave(vbus.paths[1], node=3).start():
        obs = Observer(mqtt, broker.port)
        try:
            buses = [{"name": "toys", "port": vbus.paths[0], "protocol": "toy", "nodes": [3],
                      "poll_data": b"abc".hex(), "poll_interval": 0.05}]
            with Bridge(bridge_config(broker.port, str(tmp_path / "state"), buses)) as bridge:
                assert bridge.wait_connected(WAIT)
                obs.wait_for("fap/toys/3/rx", lambda d: d["data"] == b"cba".hex())   # polled, reversed
                obs.wait_for("fap/toys/3/state", lambda d: d["state"] == "active")
                obs.publish("fap/toys/3/tx", {"id": "t1", "data": b"hello".hex()})
                (reply,) = obs.wait_for("fap/toys/3/rx", lambda d: d.get("reply_to") == "t1")
                assert reply["data"] == b"olleh".hex()
                obs.publish("fap/toys/12/tx", {"id": "t2", "data": "00"})   # past the toy's NODE_MAX
                obs.wait_for("fap/toys/12/error", lambda d: "outside 1..9 for toy" in d["error"])
                (stats,) = obs.wait_for("fap/toys/stats", lambda d: d["engine"].get("frames_rx", 0) > 0)
                assert stats["health"]["frames_tx"] >= stats["health"]["frames_rx"] > 0
        finally:
            obs.close()
