"""The message path's shortcuts (fap_py/fap.py: _first_wait, the cached C calls,
fap.types._new_message) keep every check and result of the general path."""
from __future__ import annotations

import dataclasses
import math
import pickle
import threading
import time
from typing import List, Tuple

import pytest
from conftest import WAIT

from fap_py import (
    ClosedError,
    FapTimeoutError,
    InvalidTypeError,
    InvalidValueError,
    Master,
    Message,
    QueueFullError,
    Slave,
)
from fap_py.fap import WAIT_SLICE
from fap_py.fap.types import _new_message
from fap_py.vbus import VirtualBus

Net = Tuple[Master, List[Slave]]

BAD_TIMEOUTS = [
    (True, InvalidTypeError), (False, InvalidTypeError), ("1", InvalidTypeError),
    (b"1", InvalidTypeError), ([1], InvalidTypeError),
    (-1, InvalidValueError), (-0.001, InvalidValueError), (math.nan, InvalidValueError),
    (math.inf, InvalidValueError), (10 ** 30, InvalidValueError), (3e6, InvalidValueError),
]


class Seconds(float):
    """A float subclass (like numpy.float64): takes the general check, works."""


def test_new_message_is_a_message() -> None:
    fast, slow = _new_message(3, b"abc"), Message(3, b"abc")
    assert type(fast) is Message and fast == slow and hash(fast) == hash(slow)
    assert repr(fast) == repr(slow) and dataclasses.asdict(fast) == {"source": 3, "data": b"abc"}
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.source = 4  # type: ignore[misc]
    assert pickle.loads(pickle.dumps(fast)) == slow


@pytest.mark.parametrize("bad, exc", BAD_TIMEOUTS)
def test_bad_recv_timeout_raises_the_specific_error(net: Net, bad: object, exc: type) -> None:
    master, (s, _, _) = net
    s.send(b"kept")
    with pytest.raises(exc):
        master.recv(timeout=bad)  # type: ignore[arg-type]
    assert master.recv(timeout=WAIT) == Message(s.id, b"kept")   # nothing was taken


@pytest.mark.parametrize("bad, exc", [b for b in BAD_TIMEOUTS if b[0] is not False])
def test_bad_send_timeout_raises_the_specific_error(bus: VirtualBus, bad: object, exc: type) -> None:
    # False == 0.0: it is the default "do not wait" and stays accepted
    with Slave(bus.paths[1], id=5, tx_queue=1) as s:
        s.send(b"1")
        with pytest.raises(exc):
            s.send(b"2", timeout=bad)  # type: ignore[arg-type]
        assert s.tx_pending == 1


def test_recv_timeouts_of_every_shape(net: Net) -> None:
    master, (s, _, _) = net
    for timeout in (0, 0.0, 0.01, 1, Seconds(0.02)):
        t0 = time.monotonic()
        with pytest.raises(FapTimeoutError, match=f"within {timeout} s"):
            master.recv(timeout=timeout)
        assert time.monotonic() - t0 >= float(timeout)
    s.send(b"int")
    assert master.recv(timeout=int(WAIT)).data == b"int"
    s.send(b"sub")
    assert master.recv(timeout=Seconds(WAIT)).data == b"sub"


def test_recv_timeout_longer_than_a_slice_waits_it_out(net: Net) -> None:
    # the first wait inside C is one slice, later ones what is left of the deadline
    master, _ = net
    timeout = 2.5 * WAIT_SLICE
    t0 = time.monotonic()
    with pytest.raises(FapTimeoutError):
        master.recv(timeout=timeout)
    assert time.monotonic() - t0 >= timeout


def test_send_with_a_timeout_longer_than_a_slice(bus: VirtualBus) -> None:
    with Slave(bus.paths[1], id=5, tx_queue=1) as s:
        s.send(b"1")
        t0 = time.monotonic()
        with pytest.raises(QueueFullError):
            s.send(b"2", timeout=1.5 * WAIT_SLICE)      # waited for room in slices
        assert time.monotonic() - t0 >= 1.5 * WAIT_SLICE
        with pytest.raises(QueueFullError):
            s.send(b"2", timeout=Seconds(0.01))
        assert s.tx_pending == 1


def test_close_racing_busy_callers_frees_once_and_fails_them_cleanly(bus: VirtualBus) -> None:
    # the counted use (NativeHandle._call) takes no lock: four threads call into C
    # back to back while close() runs; none may touch the freed handle (a crash),
    # each ends with ClosedError, none is left counted in
    s = Slave(bus.paths[1], id=6, tx_queue=1 << 16)
    counts = [0] * 4
    warmed = threading.Barrier(len(counts) + 1)
    errors: List[BaseException] = []

    def hammer(i: int) -> None:
        calls = (lambda: s.send(b"x", 0), s.recv_nowait, lambda: s.tx_pending, lambda: s.stats)
        try:
            while True:
                calls[counts[i] % len(calls)]()
                counts[i] += 1
                if counts[i] == 200:
                    warmed.wait(WAIT)
        except ClosedError:
            return
        except BaseException as exc:   # anything else is a defect
            errors.append(exc)

    threads = [threading.Thread(target=hammer, args=(i,)) for i in range(len(counts))]
    for t in threads:
        t.start()
    warmed.wait(WAIT)                  # every thread is calling in a loop now
    s.close()
    for t in threads:
        t.join(WAIT)
    assert not any(t.is_alive() for t in threads) and errors == []
    assert s._users == 0 and s.final_stats is not None and min(counts) >= 200
