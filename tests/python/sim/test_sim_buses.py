"""Buses: an existing port, ``--port``, a virtual bus in a named link directory, whole address
ranges, a hook that raises at run time, a YAML config."""
from __future__ import annotations

import os

import pytest

from fap_py import execasync, mikroc
from fap_py.g485 import G485Master
from fap_py.sim import Sim, loads
from fap_py.vbus import VirtualBus

from .conftest import cli


def test_existing_port_and_port_option(tmp_path):
    with VirtualBus(ports=2) as bus:
        cfg = loads(f'[[bus]]\nprotocol = "exec"\nport = "{bus.paths[1]}"\n[[bus.node]]\naddress = 9\n')
        with Sim(cfg) as sim, execasync.Master(bus.paths[0], 115200, timeout=1) as m:
            assert sim.buses[0].master_port is None
            assert m.transact(9, b"on a port") == b"on a port"
    with VirtualBus(ports=2) as bus:      # --port: the one bus on another port
        cfg = loads('[[bus]]\nprotocol = "mikroc"\n[[bus.node]]\naddress = 3\n')
        with Sim(cfg, port=bus.paths[1], baud=19200) as sim, mikroc.Master(bus.paths[0], 19200) as m:
            assert m.request(3, b"\x01", timeout=1).data == b"\x01"


def test_virtual_bus_in_a_link_dir(tmp_path):
    links = tmp_path / "links"
    cfg = loads(f'[[bus]]\nprotocol = "g485"\nvirtual = {{ link_dir = "{links}", baud = 115200 }}\n'
                '[[bus.node]]\naddress = 1\n')
    with Sim(cfg) as sim:
        assert sim.buses[0].master_port == str(links / "port0")
        assert [n for n in sorted(os.listdir(links)) if n.startswith("port")] == ["port0", "port1"]
        with G485Master(str(links / "port0"), 115200, timeout=0.2) as gm:
            assert gm.read_register(1, 7) == 1        # its ID register
    assert not (links / "port0").exists()


def test_whole_address_ranges():
    cfg = loads('[[bus]]\nname = "e"\nprotocol = "exec"\n[[bus.node]]\nrange = [1, 254]\n'
                '[[bus]]\nname = "m"\nprotocol = "mikroc"\n[[bus.node]]\nrange = [0, 49]\n'
                '[[bus.node]]\nrange = [51, 255]\n'
                '[[bus]]\nname = "g"\nprotocol = "g485"\n[[bus.node]]\nrange = [1, 126]\n')
    with Sim(cfg) as sim:
        e, m, g = (b.master_port for b in sim.buses)
        with execasync.Master(e, 115200, timeout=0.5, retries=1) as em:
            assert [em.transact(n, bytes([n])) for n in range(1, 255)] == \
                [bytes([n]) for n in range(1, 255)]
        with mikroc.Master(m, 19200) as mm:
            for n in (0, 1, 49, 51, 200, 255):
                assert mm.request(n, bytes([n]), timeout=1).data == bytes([n])
        with G485Master(g, 115200, timeout=0.2) as gm:
            for n in (1, 2, 63, 125, 126):
                assert gm.read_register(n, 7) == n
        counts = {b["name"]: b["requests"] for b in sim.status()["buses"]}
        assert counts["e"] == 254 and counts["m"] == 6


def test_hook_that_raises_at_run_time(tmp_path, monkeypatch):
    (tmp_path / "simhook_rt.py").write_text(
        "def value(t, state):\n    state['n'] = state.get('n', 0) + 1\n"
        "    if state['n'] == 2:\n        raise ValueError('second call fails')\n    return state['n']\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    cfg = loads('[[bus]]\nprotocol = "exec"\n[[bus.node]]\naddress = 2\nanswer = "value"\nsize = 1\n'
                'value = { kind = "hook", function = "simhook_rt:value" }\n')
    with Sim(cfg) as sim, execasync.Master(sim.buses[0].master_port, 115200, timeout=0.1, retries=0) as m:
        assert m.transact(2, b"") == b"\x01"
        with pytest.raises(execasync.NoReplyError):
            m.transact(2, b"")
        assert m.transact(2, b"") == b"\x03"          # the sim goes on
        node = sim.status()["buses"][0]["nodes"][0]
        assert node["errors"] == 1 and node["requests"] == 3


def test_yaml_config_runs(tmp_path):
    pytest.importorskip("yaml")
    path = tmp_path / "site.yaml"
    path.write_text("sim:\n  seed: 2\nbus:\n  - protocol: exec\n    node:\n      - address: 4\n"
                    "        answer: table\n        table:\n          - {request: '01*', reply: '0a'}\n")
    assert cli("sim", "--check", str(path)).returncode == 0
    from fap_py.sim import load
    with Sim(load(str(path))) as sim, execasync.Master(sim.buses[0].master_port, 115200, timeout=1) as m:
        assert m.transact(4, b"\x01\x02") == b"\x0a"
