"""``fap g485 sim`` is a one-bus ``fap sim`` site (fap_py.sim): the device rules the old
simulator had, through the sim's responder (ID changes, baud-detection loss, reopen)."""
from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys

from fap_py.g485 import G485Master, NoResponseError
from fap_py.sim import Sim


def _args(port: str, *addresses: int, **kw: object) -> argparse.Namespace:
    base = {"port": port, "address": list(addresses), "eeprom_dir": None, "wake_up_loss": False,
            "seed": 0, "baud": 115200}
    base.update(kw)
    return argparse.Namespace(**base)


def test_the_site_is_one_g485_bus(tmp_path) -> None:
    from fap_py.commands.protocols.g485 import sim_config

    cfg = sim_config(_args("/dev/ttyX", 1, 4, eeprom_dir=str(tmp_path), wake_up_loss=True, seed=5))
    assert cfg == {"sim": {"seed": 5}, "bus": [{
        "name": "g485", "protocol": "g485", "port": "/dev/ttyX", "baud": 115200, "node": [
            {"address": 1, "eeprom": str(tmp_path / "g485-1.json"), "wake_up_loss": True},
            {"address": 4, "eeprom": str(tmp_path / "g485-4.json"), "wake_up_loss": True}]}]}


def test_wake_up_loss_eats_the_first_burst_whoever_it_was_for(vbus) -> None:
    """Baud detection loses the first burst on the line: device 1 wakes on a request for 2."""
    from fap_py.commands.protocols.g485 import sim_config

    with Sim(sim_config(_args(vbus.paths[1], 1, 2, wake_up_loss=True))), \
            G485Master(vbus.paths[0], timeout=0.1, retries=0, wake_up=False) as master:
        try:
            master.read(2, 7)
            raise AssertionError("device 2 answered the burst it lost to baud detection")
        except NoResponseError:
            pass
        assert master.read(1, 7) == b"\x01"      # the burst for 2 woke device 1 as well
        assert master.read(2, 7) == b"\x02"


def test_a_device_answers_at_its_new_id(vbus) -> None:
    from fap_py.commands.protocols.g485 import sim_config

    with Sim(sim_config(_args(vbus.paths[1], 1, 2))) as sim, \
            G485Master(vbus.paths[0], timeout=0.1, retries=1) as master:
        master.change_id(1, 9)
        assert master.read(9, 7) == b"\x09"
        assert master.scan(range(1, 12)) == [2, 9]
        assert sorted(n["address"] for n in sim.status()["buses"][0]["nodes"]) == [2, 9]


def test_eeprom_id_is_where_the_device_answers(vbus, tmp_path) -> None:
    """An EEPROM image that holds another ID: the device answers there from power-on."""
    from fap_py.commands.protocols.g485 import sim_config

    args = _args(vbus.paths[1], 3, eeprom_dir=str(tmp_path))
    with Sim(sim_config(args)), G485Master(vbus.paths[0], timeout=0.1, retries=1) as master:
        master.change_id(3, 12, save=True)
    with Sim(sim_config(args)), G485Master(vbus.paths[0], timeout=0.1, retries=1) as master:
        assert master.read(12, 7) == b"\x0c"


def test_cli_reopens_after_an_unplug_and_counts_it(tmp_path) -> None:
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2, seed=3) as bus:
        proc = subprocess.Popen([sys.executable, "-m", "fap_py", "g485", "sim", "--port", bus.paths[1],
                                 "--address", "1", "--json"], stdout=subprocess.PIPE, text=True,
                                cwd=tmp_path)
        try:
            assert proc.stdout is not None
            ready = json.loads(proc.stdout.readline())
            assert ready == {"event": "ready", "port": bus.paths[1], "addresses": [1]}
            with G485Master(bus.paths[0], timeout=0.1, retries=0) as master:
                assert master.read(1, 7) == b"\x01"
                bus.disconnect(1, 0.1)        # the sim's port hangs up, then comes back
                assert master.read(1, 7, retries=40) == b"\x01"
        finally:
            proc.send_signal(signal.SIGTERM)
            out, _ = proc.communicate(timeout=30)
        assert proc.returncode == 0
        summary = json.loads(out.splitlines()[-1])
        assert summary["event"] == "summary" and summary["reopened"] == 1
        assert summary["replies"] >= 2 and summary["packets"] >= summary["replies"]
