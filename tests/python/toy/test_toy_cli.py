"""`fap` picks up the toy protocol's command plug-in (toyproto/commands/protocols/toy.py)
through the protocol table, with no edit to fap_py: `fap toy` is listed and talks to a toy
slave on a virtual bus, in this process and as a program that sees the toy only through
its environment."""

import json
import subprocess
import sys

from toyproto import binding

from fap_py.cli import main
from fap_py.vbus import VirtualBus


def test_fap_help_lists_toy(capsys):
    assert main(["--help"]) == 0
    assert "    toy " in capsys.readouterr().out


def test_toy_request_against_a_toy_slave(capsys):
    with VirtualBus(ports=2) as bus, binding.Slave(bus.paths[1], node=2).start() as slave:
        assert main(["toy", "request", "--port", bus.paths[0], "--node", "2", "--json", "010203"]) == 0
        assert json.loads(capsys.readouterr().out) == {"event": "reply", "node": 2, "data": "030201"}
        assert slave.stats.frames_rx == 1


def test_toy_command_errors_use_the_cli_exit_codes(capsys):
    with VirtualBus(ports=2) as bus:
        assert main(["toy", "request", "--port", bus.paths[0], "--node", "2", "--timeout", "0.05", "01"]) == 1
        err = capsys.readouterr().err
        assert err.startswith("fap: ") and err.count("\n") == 1     # no slave: one line, exit 1
    assert main(["toy", "request", "--port", "/nonexistent/tty", "--node", "2", "01"]) == 3


def test_the_program_finds_toy_through_its_environment(toy_env, tmp_path):
    with VirtualBus(ports=2) as bus, binding.Slave(bus.paths[1], node=3).start():
        run = [sys.executable, "-m", "fap_py"]
        out = subprocess.run(run + ["--help"], capture_output=True, text=True, timeout=60,
                             env=toy_env, cwd=tmp_path).stdout
        assert "    toy " in out
        p = subprocess.run(run + ["toy", "request", "--port", bus.paths[0], "--node", "3", "6869"],
                           capture_output=True, text=True, timeout=60, env=toy_env, cwd=tmp_path)
        assert p.returncode == 0 and p.stdout == 'node 3: 69 68  "ih"\n', p.stderr
