"""A mixed site driven by the real masters on its virtual buses, and every fault kind reaching
each master as its documented error, counted, and stopping when removed."""
from __future__ import annotations

import pytest

from fap_py import execasync, fap, mikroc
from fap_py.errors import FapTimeoutError, FrameError
from fap_py.g485 import G485Master
from fap_py.g485.errors import CheckByteError, G485FrameError, NoResponseError
from fap_py.sim import ManualClock, Sim, loads

SITE = """\
[sim]
seed = 3

[[bus]]
name = "ex"
protocol = "exec"
[[bus.node]]
address = 5
[[bus.node]]
range = [1, 4]
answer = "table"
table = [{ request = "01??", reply = "aa" }, { request = "02*", reply = "bbcc" }]
default = "ff"
[[bus.node]]
address = 254
answer = "value"
value = { kind = "counter", start = 7 }

[[bus]]
name = "mc"
protocol = "mikroc"
[[bus.node]]
address = 7
answer = "table"
table = [{ request = "01??", reply = "aa" }]
[[bus.node]]
address = 255
[[bus.node]]
address = 0

[[bus]]
name = "g"
protocol = "g485"
[[bus.node]]
address = 9
registers = [{ register = 10, type = "u16", value = { kind = "steps", values = [1000, 2000] } },
             { register = 20, access = "R", initial = 42 }]
[[bus.node]]
address = 126
"""


@pytest.fixture(scope="module")
def site():
    with Sim(loads(SITE, "site.toml"), clock=ManualClock()) as sim:
        ex, mc, g = (b.master_port for b in sim.buses)
        with execasync.Master(ex, 115200, timeout=0.1, retries=0) as em, \
                mikroc.Master(mc, 19200) as mm, \
                G485Master(g, 115200, timeout=0.1, retries=0) as gm:
            yield sim, em, mm, gm


def test_mixed_site_answers(site):
    sim, em, mm, gm = site
    assert em.transact(5, b"hello") == b"hello"                 # echo
    assert em.transact(1, b"\x01\x09") == b"\xaa"               # table, ?? wildcard
    assert em.transact(4, b"\x02\x01\x02\x03") == b"\xbb\xcc"   # table, * rest
    assert em.transact(3, b"\x09") == b"\xff"                    # table default
    assert [em.transact(254, b"") for _ in range(2)] == [b"\x00\x07", b"\x00\x08"]  # counter
    assert mm.request(7, b"\x01\x00", timeout=1).data == b"\xaa"
    assert mm.request(255, b"\x01\x02\x03", timeout=1).data == b"\x01\x02\x03"   # both ends
    assert mm.request(0, b"\x05", timeout=1).data == b"\x05"
    assert gm.read(9, 10, 2) == (1000).to_bytes(2, "big")       # typed register, steps
    assert gm.read(9, 10, 2) == (2000).to_bytes(2, "big")
    assert gm.read_register(9, 20) == 42
    gm.write(126, 30, b"\x11")
    assert gm.read_register(126, 30) == 0x11
    st = sim.status()
    ex = st["buses"][0]
    assert {n["address"]: n["requests"] for n in ex["nodes"]}[254] == 2
    assert st["requests"] >= 12


CALLS = {
    "exec": lambda em, mm, gm: em.transact(5, b"hi"),
    "mikroc": lambda em, mm, gm: mm.request(7, b"\x01\x00", timeout=0.1),
    "g485": lambda em, mm, gm: gm.read_register(126, 8),
}
GOOD = {"exec": b"hi", "mikroc": mikroc.Message(7, b"\xaa", False), "g485": 0}
NODE = {"exec": 5, "mikroc": 7, "g485": 126}
BUS = {"exec": "ex", "mikroc": "mc", "g485": "g"}

#: the documented error of each fault kind at each master (docs/sim.md, "Faults")
EXPECTED = {
    "exec": {"off": execasync.NoReplyError, "no_reply": execasync.NoReplyError,
             "late_reply": execasync.NoReplyError, "bad_crc": execasync.CorruptReplyError,
             "wrong_address": execasync.NoReplyError, "garbage": execasync.NoReplyError,
             "truncated": execasync.NoReplyError},
    "mikroc": {"off": FapTimeoutError, "no_reply": FapTimeoutError, "late_reply": FapTimeoutError,
               "bad_crc": mikroc.ChecksumError, "wrong_address": FrameError,
               "garbage": FapTimeoutError, "truncated": FapTimeoutError},
    "g485": {"off": NoResponseError, "no_reply": NoResponseError, "late_reply": NoResponseError,
             "bad_crc": CheckByteError, "wrong_address": NoResponseError,
             "garbage": G485FrameError, "truncated": G485FrameError},
}
# hung: nothing, like off, until the fault is removed; split with a gap past the masters'
# 0.1 s timeouts: the first half only, so each master sees what truncated gives
for _proto, _errs in EXPECTED.items():
    _errs["hung"] = _errs["off"]
    _errs["split"] = _errs["truncated"] if _proto != "mikroc" else FapTimeoutError

#: the parameters each kind is added with here
PARAMS = {"late_reply": {"ms": 300}, "split": {"ms": 300}}


def _node(st, proto):
    return [n for b in st["buses"] if b["name"] == BUS[proto] for n in b["nodes"]
            if n["address"] == NODE[proto]][0]


@pytest.mark.parametrize("proto", ["exec", "mikroc", "g485"])
@pytest.mark.parametrize("kind", ["off", "no_reply", "late_reply", "bad_crc", "wrong_address",
                                  "garbage", "truncated", "hung", "split"])
def test_fault_reaches_master_and_stops(site, proto, kind):
    sim, em, mm, gm = site
    call = lambda: CALLS[proto](em, mm, gm)   # noqa: E731
    assert call() == GOOD[proto]
    before = sim.status()["faults_applied"][kind]
    replies = _node(sim.status(), proto)["replies"]
    f = sim.add_fault(kind, bus=BUS[proto], node=NODE[proto], **PARAMS.get(kind, {}))
    with pytest.raises(EXPECTED[proto][kind]) as e:
        call()
    if kind == "hung":      # latched: every later request unanswered too, until removed
        with pytest.raises(EXPECTED[proto][kind]):
            call()
        assert f"{BUS[proto]}:{NODE[proto]}" in sim.faults_list()[-1]["hung_nodes"]
    if kind == "wrong_address" and proto == "mikroc":
        assert "reply from slave 8, expected 7" in str(e.value)
    st = sim.status()
    assert st["faults_applied"][kind] > before
    node = _node(st, proto)
    assert node["faults"][kind] >= 1
    node["replies"] = replies
    if kind in ("late_reply", "split"):   # the (rest of the) reply goes out after the master gave up
        assert sim.wait_for(lambda s: _node(s, proto)["replies"] > node["replies"], 5)
    sim.remove_fault(f["id"])
    applied = sim.status()["faults_applied"][kind]
    ok = None
    for _ in range(2):   # a late reply still on the wire may meet the first request
        try:
            ok = call()
            break
        except (FapTimeoutError, FrameError):
            continue
    assert ok == GOOD[proto]
    assert sim.status()["faults_applied"][kind] == applied     # no longer applied


def test_probability_is_seeded(site):
    sim, em, mm, gm = site
    f = sim.add_fault("no_reply", bus="ex", node=5, probability=0.5, seed=11)
    outcome = []
    for _ in range(12):
        try:
            em.transact(5, b"p")
            outcome.append(1)
        except execasync.NoReplyError:
            outcome.append(0)
    sim.remove_fault(f["id"])
    assert 0 < sum(outcome) < 12
    import random
    rng = random.Random(11)
    assert outcome == [0 if rng.random() < 0.5 else 1 for _ in range(12)]


def test_fault_for_all_nodes_and_unknown_kinds(site):
    sim, em, mm, gm = site
    f = sim.add_fault("off", bus="ex")
    for node in (1, 5, 254):
        with pytest.raises(execasync.NoReplyError):
            em.transact(node, b"x")
    sim.remove_fault("all")
    assert em.transact(5, b"x") == b"x"
    from fap_py.sim import FaultError
    with pytest.raises(FaultError, match="unknown fault kind"):
        sim.add_fault("explode")
    with pytest.raises(FaultError, match="no bus is named"):
        sim.add_fault("off", bus="nope")
    with pytest.raises(FaultError, match="no fault has id"):
        sim.remove_fault(9999)
    assert f["id"] not in [x["id"] for x in sim.faults_list()]


FAP_SITE = """\
[[bus]]
name = "f"
protocol = "fap"
[[bus.node]]
address = 3
answer = "echo"
periodic = [{ every = 0.05, value = { kind = "counter" } }]
[[bus.node]]
address = 31
"""


def test_fap_slaves_periodic_echo_and_off():
    with Sim(loads(FAP_SITE, "fap.toml")) as sim, \
            fap.Master(sim.buses[0].master_port, 115200, slaves=[3, 31], id_cycle=0.05,
                       data_done_timeout=0.2, id_answer_timeout=0.1) as m:
        m.wait_active([3, 31], timeout=5)
        first = [m.recv(timeout=5) for _ in range(2)]
        assert [x.source for x in first] == [3, 3]
        assert int.from_bytes(first[1].data, "big") == int.from_bytes(first[0].data, "big") + 1
        m.send(b"ping", to=3)
        for _ in range(100):
            msg = m.recv(timeout=5)
            if msg.data == b"ping":
                break
        assert msg.source == 3 and msg.data == b"ping"
        f = sim.add_fault("off", node=31)
        ev = None
        for _ in range(50):
            ev = m.wait_event(timeout=5)
            if ev.id == 31 and not m.is_active(31):
                break
        assert not m.is_active(31)
        sim.remove_fault(f["id"])
        m.wait_active([31], timeout=5)
        st = sim.status()["buses"][0]
        assert {n["address"]: n["faults"].get("off", 0) for n in st["nodes"]} == {3: 0, 31: 1}
        with pytest.raises(Exception, match="not implemented"):
            sim.add_fault("bad_crc", bus="f")


def test_split_with_a_short_gap_is_reassembled(site):
    """A reply in two pieces 20 ms apart, inside every master's timeout: each master puts the
    pieces together (the masters read a reply to its end, not one read's worth)."""
    sim, em, mm, gm = site
    f = sim.add_fault("split", bus=None, node="all", ms=20)
    try:
        for proto in ("exec", "mikroc", "g485"):
            assert CALLS[proto](em, mm, gm) == GOOD[proto]
        assert sim.faults_list()[-1]["applied"] >= 3
    finally:
        sim.remove_fault(f["id"])


@pytest.mark.parametrize("kind", ["bit_errors", "byte_drops"])
def test_byte_level_faults_reach_every_master_and_are_counted(site, kind):
    """rate 1: every byte of the reply hit; each master reports one of its documented errors."""
    sim, em, mm, gm = site
    errors = (execasync.ExecAsyncError, FapTimeoutError, FrameError, mikroc.ChecksumError,
              NoResponseError, G485FrameError, CheckByteError)
    f = sim.add_fault(kind, rate=1.0, seed=5)
    try:
        for proto in ("exec", "mikroc", "g485"):
            with pytest.raises(errors):
                CALLS[proto](em, mm, gm)
        assert sim.faults_list()[-1]["applied"] == 3
        assert sim.faults_list()[-1]["rate"] == 1.0
    finally:
        sim.remove_fault(f["id"])
    for proto in ("exec", "mikroc", "g485"):
        for _ in range(2):     # the first request may meet the damaged tail of the last reply
            try:
                assert CALLS[proto](em, mm, gm) == GOOD[proto]
                break
            except errors:
                continue
        else:
            raise AssertionError(f"{proto} did not recover after {kind} was removed")


def test_g485_error_reply_is_the_devices_error_word(site):
    sim, em, mm, gm = site
    from fap_py.sim import FaultError
    with pytest.raises(FaultError, match="not implemented"):
        sim.add_fault("error_reply", bus="ex", node=5)
    f = sim.add_fault("error_reply", bus="g", node=126, word=0x0104)
    try:
        assert gm.error_word(126) & 0x0104 == 0x0104
    finally:
        sim.remove_fault(f["id"])
    assert sim.status()["faults_applied"]["error_reply"] >= 1


def test_parameters_are_refused_where_they_do_not_belong(site):
    sim, em, mm, gm = site
    from fap_py.sim import FaultError
    for kind, kw, match in (("off", {"ms": 5}, "not a parameter of off"),
                            ("bit_errors", {"rate": 1.5}, "rate must be"),
                            ("error_reply", {"word": 0}, "word must be"),
                            ("error_reply", {"word": 1.5}, "word must be"),
                            ("off", {"every": 2}, "every needs for"),
                            ("off", {"duration": 3, "every": 2}, "every needs for"),
                            ("off", {"at": -1}, "at must be"),
                            ("off", {"duration": float("nan")}, "for must be")):
        with pytest.raises(FaultError, match=match):
            sim.add_fault(kind, bus="ex", **kw)


@pytest.mark.parametrize("kind", ["bit_errors", "byte_drops"])
def test_request_direction_damages_what_the_node_hears(site, kind):
    """direction request, rate 1: every request is damaged on its way in, so no node
    executes or answers it (each master times out), and the node counts it as damaged,
    not as a request; rate 0: every request comes through whole."""
    sim, em, mm, gm = site
    timeouts = (execasync.NoReplyError, FapTimeoutError, NoResponseError)

    def node(proto):
        bus = next(b for b in sim.status()["buses"] if b["name"] == BUS[proto])
        return next(n for n in bus["nodes"] if n["address"] == NODE[proto])

    before = {p: node(p) for p in CALLS}
    f = sim.add_fault(kind, rate=1.0, seed=5, direction="request")
    try:
        assert sim.faults_list()[-1]["direction"] == "request"
        for proto in CALLS:
            with pytest.raises(timeouts):
                CALLS[proto](em, mm, gm)
            got = node(proto)
            assert got["requests_damaged"] == before[proto]["requests_damaged"] + 1, proto
            assert got["requests"] == before[proto]["requests"], proto       # never executed
    finally:
        sim.remove_fault(f["id"])
    f = sim.add_fault(kind, rate=0.0, direction="request")
    try:
        for proto in CALLS:
            assert CALLS[proto](em, mm, gm) == GOOD[proto]
    finally:
        sim.remove_fault(f["id"])
    from fap_py.sim import FaultError
    with pytest.raises(FaultError, match="replies only"):
        sim.add_fault("garbage", direction="request")
    with pytest.raises(FaultError, match="direction must be"):
        sim.add_fault(kind, direction="both")
