"""Value generators on a fake clock (no sleeps): every kind, seeded randomness, hooks."""
from __future__ import annotations

import pytest

from fap_py import execasync
from fap_py.sim import ManualClock, Sim, loads
from fap_py.sim._generators import GeneratorError, make, to_bytes


def test_kinds():
    assert make({"kind": "const", "value": 7})(123.0) == 7
    c = make({"kind": "counter", "start": 10, "step": 5})
    assert [c(0) for _ in range(3)] == [10, 15, 20]
    c = make({"kind": "counter", "start": 0, "step": 1, "every": 2})
    assert [c(t) for t in (0, 1.9, 2, 7)] == [0, 0, 1, 3]
    w = make({"kind": "counter", "start": 0, "step": 1, "wrap": 3})
    assert [w(0) for _ in range(5)] == [0, 1, 2, 0, 1]
    r = make({"kind": "ramp", "low": 0, "high": 100, "period": 10})
    assert [r(t) for t in (0, 5, 9.5, 10)] == [0, 50, 95, 0]
    s = make({"kind": "sine", "amplitude": 2, "offset": 1, "period": 4})
    assert s(0) == pytest.approx(1) and s(1) == pytest.approx(3) and s(3) == pytest.approx(-1)
    q = make({"kind": "square", "low": 1, "high": 9, "period": 2, "duty": 0.25})
    assert [q(t) for t in (0, 0.4, 0.6, 2.1)] == [9, 9, 1, 9]
    st = make({"kind": "steps", "values": [3, 1, 4]})
    assert [st(0) for _ in range(4)] == [3, 1, 4, 3]
    st = make({"kind": "steps", "values": [3, 1, 4], "every": 1})
    assert [st(t) for t in (0, 1.5, 2, 3)] == [3, 1, 4, 3]


def test_random_is_seeded_and_reproducible():
    a = make({"kind": "random", "low": 0, "high": 1000, "seed": 5})
    b = make({"kind": "random", "low": 0, "high": 1000, "seed": 5})
    xs = [a(0) for _ in range(20)]
    assert xs == [b(0) for _ in range(20)]
    assert all(0 <= x <= 1000 and x == int(x) for x in xs) and len(set(xs)) > 10
    c = make({"kind": "random", "low": 0, "high": 1000}, seed=6)
    assert [c(0) for _ in range(20)] != xs


def test_hook(tmp_path, monkeypatch):
    (tmp_path / "simhook_a.py").write_text(
        "def value(t, state):\n    state['n'] = state.get('n', 0) + 1\n    return t * 10 + state['n']\n"
        "def broken(t, state):\n    raise KeyError('nope')\n"
        "def text(t, state):\n    return 'x'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    h = make({"kind": "hook", "function": "simhook_a:value"})
    assert [h(1), h(2)] == [11, 22]
    with pytest.raises(GeneratorError, match="KeyError"):
        make({"kind": "hook", "function": "simhook_a:broken"})(0)
    with pytest.raises(GeneratorError, match="not a number"):
        make({"kind": "hook", "function": "simhook_a:text"})(0)


def test_to_bytes_clamps():
    assert to_bytes(70000, 2) == b"\xff\xff" and to_bytes(-5, 2) == b"\x00\x00"
    assert to_bytes(-2, 2, signed=True) == b"\xff\xfe" and to_bytes(258, 2, "little") == b"\x02\x01"


def test_fake_clock_drives_a_node_through_a_real_master():
    """A sine node read by the exec master at clock times set by hand: the value follows."""
    cfg = loads('[[bus]]\nprotocol = "exec"\n[[bus.node]]\naddress = 3\nanswer = "value"\n'
                'value = { kind = "sine", amplitude = 1000, offset = 2000, period = 8 }\n'
                '[[bus.node]]\naddress = 4\nanswer = "value"\nsigned = true\nsize = 1\n'
                'value = { kind = "square", low = -5, high = 5, period = 2 }\n')
    clock = ManualClock()
    with Sim(cfg, clock=clock) as sim, \
            execasync.Master(sim.buses[0].master_port, 115200, timeout=1.0, retries=1) as m:
        got = []
        for t in (0, 2, 4, 6):
            clock.t = t
            got.append(int.from_bytes(m.transact(3, b"?"), "big"))
        assert got == [2000, 3000, 2000, 1000]
        clock.t = 0.5
        assert m.transact(4, b"") == b"\x05"
        clock.t = 1.5
        assert m.transact(4, b"") == b"\xfb"
