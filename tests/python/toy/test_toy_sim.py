"""`fap sim` picks up the toy protocol's sim plug-in (toyproto/sim/protocols/toy.py)
through the protocol table, with no edit to fap_py: a toy bus from a config file answers
the toy master, and a fault switched on over the control socket reaches it."""

import json
import subprocess
import sys

import pytest
from toyproto import binding as toy

from fap_py.errors import FapTimeoutError


def test_fap_sim_runs_a_toy_bus(toy_env, tmp_path):
    cfg = tmp_path / "toy.toml"
    links, sock = tmp_path / "links", tmp_path / "sim.sock"
    cfg.write_text(f'[[bus]]\nname = "t"\nprotocol = "toy"\nvirtual = {{ link_dir = "{links}" }}\n'
                   '[[bus.node]]\naddress = 3\n')
    argv = [sys.executable, "-m", "fap_py", "sim", str(cfg), "--json", "--control", f"unix:{sock}"]
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=toy_env,
                         cwd=tmp_path)
    try:
        ready = json.loads(p.stdout.readline())     # the sim says when it serves: no sleep
        assert ready["event"] == "ready", ready
        port0 = ready["buses"][0]["master_port"]
        m = toy.Master(port0, timeout=1.0)
        try:
            assert m.request(3, b"abc") == b"cba"
            ctl = [sys.executable, "-m", "fap_py", "sim", "fault", "add", "no_reply", "--node", "3",
                   "--control", f"unix:{sock}"]
            r = subprocess.run(ctl, capture_output=True, text=True, timeout=30, env=toy_env)
            assert r.returncode == 0, r.stderr
            with pytest.raises(FapTimeoutError):
                m.request(3, b"abc")
        finally:
            m.close()
    finally:
        p.terminate()
        p.wait(timeout=10)
    assert p.returncode == 0, p.stderr.read()
