"""`fap soak` picks up the toy protocol's soak plug-in (toyproto/soak/toy.py) through the
protocol table, with no edit to fap_py: a short real run (slave processes, a slave killed
and restarted, the master's port taken away) reports the toy's verdict."""

import json
import subprocess
import sys

from fap_py.cli import main


def test_soak_lists_the_toy(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["soak", "--help"]) == 0
    assert "{fap,exec,mikroc,g485,toy,all}" in capsys.readouterr().out


def test_toy_soak_reports_its_verdict(toy_env, tmp_path):
    # 6 s: the port comes back at 5 s, leaving time for the reopen and a good exchange;
    # no bit errors or drops: the toy's one-byte sum would let some through (a flaky verdict)
    argv = [sys.executable, "-m", "fap_py", "soak", "--protocol", "toy", "--seconds", "6", "--slaves", "2",
            "--bit-error-rate", "0", "--drop-rate", "0", "--sample", "0.5", "--json"]
    p = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=toy_env, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert len(lines) == 1, p.stdout
    res = json.loads(lines[0])
    assert res["protocol"] == "toy" and res["ok"] is True and res["slaves"] == 2
    f = res["faults"]
    assert f["slave_killed"] == 1 and f["port_disconnects"] == 1
    assert res["sent"] > 20 and res["delivered_intact"] > 0 and res["corrupted"] == 0
    assert res["every_loss_counted"] is True
    assert res["port_errors"] >= 1                  # the port went away
    assert res["slave_answers"] > 0                 # the slave processes' own counters came back
    assert res["resources"]["samples"] >= 2


def test_toy_soak_slave_limit_comes_from_the_toy_row(capsys):
    from toyproto import binding
    assert main(["soak", "--protocol", "toy", "--slaves", str(binding.NODE_MAX + 1)]) == 2
    assert f"--slaves 1..{binding.NODE_MAX}" in capsys.readouterr().err
