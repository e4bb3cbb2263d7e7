"""`fap soak` as a command over the soak engine (fap_py.soak): the protocols, their aliases and
the slave limit come from the protocol table; the harness's channel model counts what a check
lets through."""
from __future__ import annotations

import json
import os
import subprocess

from fap_py import _protocols
from fap_py.soak import harness
from fap_py.vbus import MAX_PORTS

from .conftest import fap_cmd


def test_protocol_choices_are_the_table(fap) -> None:
    r = fap("soak", "--help")
    assert "{" + ",".join(_protocols.names()) + ",all}" in r.out.replace("\n", "")


def test_unknown_protocol_is_a_usage_error(fap) -> None:
    r = fap("soak", "--protocol", "modbus")
    assert r.code == 2 and "invalid choice: 'modbus'" in r.err


def test_an_alias_runs_the_protocol_under_its_one_name(fap) -> None:
    # a short real run, faults on the bus off: the alias must reach the exec soak
    r = fap("soak", "--protocol", "execasync", "--seconds", "0.6", "--slaves", "1",
            "--bit-error-rate", "0", "--drop-rate", "0", "--json")
    assert r.code == 0, r.err
    res = json.loads(r.out)
    assert res["protocol"] == "exec" and res["transactions"] > 0 and res["ok"] is True


def test_slave_limit_comes_from_the_table(fap) -> None:
    for p in _protocols.PROTOCOLS:
        top = p.node_max if p.broadcast is None or not 1 <= p.broadcast <= p.node_max else p.broadcast - 1
        assert harness.max_slaves(p.name) == min(top - max(1, p.node_min) + 1, MAX_PORTS - 1)
    most = min(harness.max_slaves(n) for n in _protocols.names())
    r = fap("soak", "--slaves", str(most + 1))
    assert r.code == 2 and r.err == (f"fap: error: need --slaves 1..{most}, --seconds > 0, --sample > 0 "
                                     f"(not {most + 1}, 30.0, 1.0)\n")
    assert f"slave processes (1..{most})" in fap("soak", "--help").out


def test_channel_model_counts_what_a_check_lets_through() -> None:
    cfg = harness.Config(check8_seconds=0.05, check8_ber=0.02)

    def frame(rnd):
        return rnd.randbytes(8)

    perfect = harness.channel_soak("x", cfg, frame, lambda wire: [])   # catches all, delivers none
    assert perfect["damaged_on_wire"] > 0 and perfect["damage_undetected"] == 0
    assert perfect["damage_detected"] == perfect["damaged_on_wire"]
    assert perfect["clean_but_lost"] == perfect["frames"] - perfect["damaged_on_wire"]
    blind = harness.channel_soak("x", cfg, frame, lambda wire: [wire])   # no check at all
    assert blind["damage_undetected"] == blind["damaged_on_wire"] > 0
    assert blind["delivered_intact"] == blind["frames"] - blind["damaged_on_wire"]
    assert blind["undetected_per_damaged_frame"] == 1.0


def test_a_bad_extra_protocol_is_one_usage_line() -> None:
    env = dict(os.environ, **{_protocols.ENV_EXTRA: "no_such_module:ROW"})
    p = subprocess.run(fap_cmd("soak", "--help"), capture_output=True, text=True, timeout=60, env=env)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.startswith("fap: error: FAP_EXTRA_PROTOCOLS: cannot load 'no_such_module:ROW'")
    assert p.stderr.count("\n") == 1
