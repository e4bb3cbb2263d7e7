"""The scheduler alone (sans-I/O): deficit round-robin by wire time, weights,
priorities, bounded queues. Costs are given, so every figure is exact."""
from __future__ import annotations

import pytest

from fap_py.serve import ClientQueueFullError
from fap_py.serve._sched import Scheduler


def _run(s: Scheduler, cost: dict, rounds: int, backlog: bool = True) -> dict:
    """Clients that always have work: with a backlog (a request queued behind the one
    running), or one request at a time (the next one queued once the answer came)."""
    used = dict.fromkeys(cost, 0.0)
    for _ in range(rounds):
        key, item = s.next()
        if backlog:
            s.push(key, item)
        s.charge(key, cost[key])
        used[key] += cost[key]
        if not backlog:
            s.push(key, item)
    return used


def test_equal_weights_share_wire_time_not_transactions():
    s = Scheduler(quantum=0.005)
    s.add(1, limit=4)
    s.add(2, limit=4)
    s.push(1, "a")
    s.push(2, "b")
    used = _run(s, {1: 0.001, 2: 0.010}, 2000)     # client 2's transactions are 10x longer
    assert used[1] / used[2] == pytest.approx(1.0, rel=0.05)


def test_one_request_at_a_time_clients_share_wire_time_too():
    s = Scheduler(quantum=0.005)
    s.add(1, limit=4)
    s.add(2, limit=4)
    s.push(1, "a")
    s.push(2, "b")
    used = _run(s, {1: 0.001, 2: 0.010}, 2000, backlog=False)
    assert used[1] / used[2] == pytest.approx(1.0, rel=0.05)


def test_weights_set_the_share():
    s = Scheduler(quantum=0.005)
    s.add(1, weight=3, limit=4)
    s.add(2, weight=1, limit=4)
    s.push(1, "a")
    s.push(2, "b")
    used = _run(s, {1: 0.002, 2: 0.002}, 4000)
    assert used[1] / used[2] == pytest.approx(3.0, rel=0.05)


def test_higher_priority_goes_first():
    s = Scheduler()
    s.add(1, priority=0)
    s.add(2, priority=2)
    s.push(1, "low")
    s.push(2, "high")
    assert s.next() == (2, "high")
    s.charge(2, 0.001)
    assert s.next() == (1, "low")


def test_a_full_queue_is_refused_and_a_removed_client_gives_back_its_queue():
    s = Scheduler()
    s.add(1, limit=2)
    s.push(1, "a")
    s.push(1, "b")
    with pytest.raises(ClientQueueFullError, match="queue full"):
        s.push(1, "c")
    assert s.remove(1) == ["a", "b"]
    assert s.next() is None and s.pending() == 0


def test_an_idle_client_keeps_its_debt_not_its_credit():
    s = Scheduler(quantum=0.005)
    s.add(1)
    s.add(2)
    s.push(1, "long")
    key, _ = s.next()
    s.charge(key, 0.050)                       # one long transaction, then idle
    assert s.share(1).deficit < 0
    s.push(1, "x")
    s.push(2, "y")
    assert s.next()[0] == 2                    # client 2 goes before the indebted client 1
