"""Scheduled faults (``at``/``for``/``every``): the schedule's arithmetic on a clock the test
sets, and one live schedule switching a fault on and off by itself in front of a real master."""
from __future__ import annotations

import threading

import pytest

from fap_py import execasync
from fap_py.sim import ManualClock, Sim, loads
from fap_py.sim._faults import Fault, FaultTable


def test_schedule_arithmetic():
    f = Fault(1, "off", at=2.0, duration=1.0, every=5.0, t0=100.0)
    assert [f.active(t) for t in (101.9, 102.0, 102.9, 103.0, 106.9, 107.0, 107.5, 108.0)] == \
        [False, True, True, False, False, True, True, False]
    assert f.next_edge(100.0) == 102.0
    assert f.next_edge(102.5) == 103.0
    assert f.next_edge(103.5) == 107.0
    once = Fault(2, "off", at=0.0, duration=1.0, t0=10.0)
    assert once.active(10.5) and not once.active(11.0) and once.expired(11.0)
    assert once.next_edge(10.5) == 11.0 and once.next_edge(11.5) is None
    plain = Fault(3, "off", t0=0.0)
    assert not plain.scheduled and plain.active(1e9) and plain.next_edge(5.0) is None


def test_table_draws_only_in_force_faults():
    t = FaultTable()
    now = [1000.0]
    t.now = lambda: now[0]
    try:
        f = t.add("no_reply", at=1.0, duration=2.0)
        assert t.draw("b", 1) == (None, None)
        now[0] = 1001.5
        assert t.draw("b", 1)[0] is f
        assert t.list()[0]["active"] is True and t.list()[0]["for"] == 2.0
        now[0] = 1003.0
        assert t.draw("b", 1) == (None, None)
        assert f.expired(now[0])
    finally:
        t.close()


SITE = """\
[[bus]]
name = "ex"
protocol = "exec"
[[bus.node]]
address = 5

[[fault]]
kind = "no_reply"
node = 5
at = 0.3
for = 0.4
"""


def test_config_schedule_switches_on_then_ends_by_itself():
    """The config's fault is in force from 0.3 s for 0.4 s: before, the node answers; the
    schedule thread switches it on (an event), then drops it (expire); after, answers again."""
    changes = []
    seen = threading.Condition()
    with Sim(loads(SITE, "s.toml"), clock=ManualClock()) as sim:
        def note() -> None:
            with seen:
                changes.append([e["event"] for e in sim.faults.events])
                seen.notify_all()

        sim.faults.listeners.append(note)
        with execasync.Master(sim.buses[0].master_port, 115200, timeout=0.1, retries=0) as m:
            if not sim.faults_list()[0]["active"]:
                assert m.transact(5, b"a") == b"a"
            with seen:
                assert seen.wait_for(lambda: any("switch" in c for c in changes), 10)
            assert sim.faults_list()[0]["active"]
            with pytest.raises(execasync.NoReplyError):
                m.transact(5, b"b")
            with seen:
                assert seen.wait_for(lambda: sim.faults_list() == [], 10)
            assert m.transact(5, b"c") == b"c"
            assert "expire" in [e["event"] for e in sim.faults.events]
            assert sim.status()["faults_applied"]["no_reply"] >= 1


def test_every_repeats_and_remove_stops_the_schedule():
    with Sim(loads(SITE.split("[[fault]]")[0], "s.toml"), clock=ManualClock()) as sim:
        flips = threading.Semaphore(0)
        sim.faults.listeners.append(flips.release)
        f = sim.add_fault("off", bus="ex", node=5, duration=0.05, every=0.1)
        assert f["every"] == 0.1 and f["for"] == 0.05
        for _ in range(4):     # on at add (a change), then off, on, off ... by the schedule
            assert flips.acquire(timeout=10)
        switches = [e for e in sim.faults.events if e["event"] == "switch"]
        assert {e["state"] for e in switches} == {"on", "off"}
        sim.remove_fault(f["id"])
        assert sim.faults_list() == []


FAP_SITE = """\
[[bus]]
name = "f"
protocol = "fap"
[[bus.node]]
address = 31
"""


def test_fap_slave_switched_off_and_on_by_a_schedule():
    """FAP slaves are opened and closed by the runner, not per transaction: the schedule thread's
    edge (a listener call) closes slave 31 (the master marks it inactive) and the expiry opens it."""
    from fap_py import fap

    with Sim(loads(FAP_SITE, "f.toml")) as sim, \
            fap.Master(sim.buses[0].master_port, 115200, slaves=[31], id_cycle=0.05,
                       data_done_timeout=0.2, id_answer_timeout=0.1) as m:
        m.wait_active([31], timeout=5)
        sim.add_fault("off", node=31, at=0.2, duration=1.0)
        for _ in range(100):
            m.wait_event(timeout=5)
            if not m.is_active(31):
                break
        assert not m.is_active(31)
        m.wait_active([31], timeout=10)     # the fault's 'for' ran out: the slave is back
        assert sim.faults_list() == []
        assert {n["address"]: n["faults"].get("off", 0) for n in sim.status()["buses"][0]["nodes"]} == {31: 1}
