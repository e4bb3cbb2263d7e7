"""mqtts:// with a throwaway CA, and a broker with a password file."""
from __future__ import annotations

import subprocess
import sys

import pytest
from bridge_helpers import WAIT, bridge_config, need
from mosquitto import MOSQUITTO, Mosquitto, make_tls


@pytest.fixture
def fap_pair():
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(2) as bus:
        with Slave(bus.paths[1], id=1) as s1:
            yield bus, s1


def _buses(bus):
    return [{"name": "line1", "port": bus.paths[0], "protocol": "fap", "slaves": [1], "id_cycle": 0.1}]


@pytest.fixture
def need_mosquitto(paho_mqtt):
    need("mosquitto", MOSQUITTO is not None)


def test_tls_with_throwaway_ca(need_mosquitto, observer_factory, fap_pair, tmp_path):
    from fap_py.bridge import Bridge

    bus, s1 = fap_pair
    tls = make_tls(str(tmp_path))
    with Mosquitto(str(tmp_path / "broker"), tls=tls) as broker:
        obs = observer_factory(broker.port, tls=tls)
        cfg = bridge_config(broker.port, str(tmp_path / "state"), _buses(bus),
                            url=f"mqtts://127.0.0.1:{broker.port}", ca=tls["ca"])
        with Bridge(cfg) as bridge:
            assert bridge.wait_connected(WAIT)
            s1.send(b"\x42")
            (m,) = obs.wait_for("fap/line1/1/rx")
            assert m["data"] == "42"
        # without our CA the server certificate is not trusted: never connected
        cfg = bridge_config(broker.port, str(tmp_path / "state2"), _buses(bus),
                            url=f"mqtts://127.0.0.1:{broker.port}")
        with Bridge(cfg) as bridge:
            assert not bridge.wait_connected(1.0)


def test_password_right_and_wrong(need_mosquitto, observer_factory, fap_pair, tmp_path):
    from fap_py.bridge import Bridge, BrokerRefusedError

    bus, s1 = fap_pair
    with Mosquitto(str(tmp_path / "broker"), users={"plant": "s3cret", "obs": "o"}) as broker:
        obs = observer_factory(broker.port, auth=("obs", "o"))
        bad = bridge_config(broker.port, str(tmp_path / "bad"), _buses(bus),
                            username="plant", password="wrong")
        with Bridge(bad) as bridge:
            with pytest.raises(BrokerRefusedError, match="refused"):
                bridge.wait_connected(WAIT)
        assert not obs.matching("fap/line1/1/state")   # nothing was published
        good = bridge_config(broker.port, str(tmp_path / "good"), _buses(bus),
                             url=f"mqtt://plant:s3cret@127.0.0.1:{broker.port}")
        with Bridge(good) as bridge:
            assert bridge.wait_connected(WAIT)
            s1.send(b"ok")
            obs.wait_for("fap/line1/1/rx", lambda d: d["data"] == b"ok".hex())
        # the command: a refused login is one line on stderr and exit 1
        conf = tmp_path / "bridge.toml"
        conf.write_text(f'[bridge]\nhost = "cli"\nstate_dir = "st"\n[broker]\n'
                        f'url = "mqtt://plant:nope@127.0.0.1:{broker.port}"\n'
                        f'[[bus]]\nname = "line1"\nport = "{bus.paths[0]}"\nprotocol = "fap"\nslaves = [1]\n')
        res = subprocess.run([sys.executable, "-m", "fap_py", "bridge", "--config", str(conf),
                              "--connect-timeout", str(WAIT)], capture_output=True, text=True,
                             timeout=WAIT + 30, cwd=str(tmp_path))
        assert res.returncode == 1, res.stderr
        lines = res.stderr.strip().splitlines()
        assert lines[-1].startswith("fap: error: broker refused the connection")

