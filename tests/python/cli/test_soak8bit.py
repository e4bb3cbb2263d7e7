"""`fap soak --protocol mikroc|g485`: the 8-bit-check protocols on the paced virtual bus.

Short real runs (slave processes, bit errors, a slave killed, the master's
port disconnected): the report must account for every message, and the
soak's own identity checks must see a corrupted message.
"""
from __future__ import annotations

import json
import random

from fap_py.soak import g485 as sg
from fap_py.soak import mikroc as sm

from .conftest import run_proc


def test_mikroc_identity_byte_catches_a_changed_sequence_or_node() -> None:
    req = sm.mikroc_request(1234, 3)
    assert len(req) == 3 and req[:2] == (1234).to_bytes(2, "big")
    # another node, or another sequence under the same hash byte: caught
    # (the keyed byte differs for these; in general 1 in 256 slips past)
    assert sm.mikroc_request(1234, 4) != req
    assert req != sm.mikroc_reply(1234, 3)


def test_g485_block_digest_detects_any_single_bit_flip() -> None:
    blk = sg.g485_block(7, 2, random.Random(1))
    assert len(blk) == sg.G485_BLOCK and sg.g485_intact(blk, 2)
    assert not sg.g485_intact(blk, 3)               # another node's block
    for i in range(len(blk)):
        for bit in range(8):
            bad = bytearray(blk)
            bad[i] ^= 1 << bit
            assert not sg.g485_intact(bytes(bad), 2)


def _soak(proto: str) -> dict:
    # 6 s: the port comes back at 5 s, leaving time for the reopen and a good exchange
    r = run_proc("soak", "--protocol", proto, "--seconds", "6", "--slaves", "2",
                 "--check8-seconds", "0.2", "--json", timeout=120)
    assert r.code == 0, r.err
    lines = r.lines()
    assert len(lines) == 1
    res = json.loads(lines[0])
    assert res["protocol"] == proto and res["ok"] is True
    f = res["faults"]
    assert f["slave_killed"] == 1 and f["port_disconnects"] == 1 and f["bus_bit_errors"] > 0
    ch = res["channel"]
    assert ch["frames"] > 0 and ch["damaged_on_wire"] >= ch["damage_undetected"]
    return res


def test_mikroc_bus_soak_accounts_for_every_message() -> None:
    res = _soak("mikroc")
    a, b = res["master_to_slaves"], res["slaves_to_master"]
    assert a["sent"] > 100 and a["delivered_intact"] > 0 and a["duplicated"] == 0
    assert a["sent"] == a["delivered_intact"] + a["lost"]
    assert b["delivered_intact"] > 0 and b["duplicated"] == 0
    assert b["replies_expected"] == b["delivered_intact"] + b["lost"]
    # a reply not received intact is a time-out, a detected frame error, a port
    # error, or a corruption the check let through (or a late reply taking its place)
    lc = b["loss_counters"]
    assert b["lost"] <= lc["no_reply"] + lc["frame_errors"] + lc["port_errors"] + \
        b["corrupted_undetected"] + b["from_wrong_node"] + b["late_replies"]


def test_g485_bus_soak_reads_back_what_it_wrote() -> None:
    res = _soak("g485")
    assert res["sent"] > 20 and res["delivered_intact"] > 0
    assert res["sent"] == res["delivered_intact"] + res["corrupted_undetected"] + \
        res["stale_read"] + res["lost"]
    assert res["every_loss_counted"] is True
    assert res["master_stats"]["reopens"] >= 1      # the port came back
