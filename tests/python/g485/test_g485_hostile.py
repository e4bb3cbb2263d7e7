"""Hostile input to every public G485 API: only the package's own exceptions, never a hang.

Issue 12 (defect 2): baud 0 was accepted and a read then blocked ~140 s,
``timeout=nan`` was accepted, ``timeout=inf`` raised OverflowError,
``SimDevice(bulk_discard_rate=5.0)`` was accepted.
"""
from __future__ import annotations

import asyncio
import math
import time
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fap_py.errors import FapError
from fap_py.g485 import G485Master, G485ValueError, Parser, SimDevice, Simulator, codec
from fap_py.g485.aio import AsyncG485Master

# anything a caller might pass by mistake
junk = st.one_of(st.none(), st.booleans(), st.integers(min_value=-2**70, max_value=2**70),
                 st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5), st.binary(max_size=5),
                 st.lists(st.integers(min_value=-300, max_value=300), max_size=4), st.just(object()))
numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(min_value=-2**70, max_value=2**70))
FAST = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))


@pytest.mark.parametrize("kwargs", [
    {"baudrate": 0}, {"baudrate": -9600}, {"baudrate": 1.5}, {"baudrate": "9600"}, {"baudrate": True},
    {"baudrate": 2**40}, {"baudrate": 12345},  # not a termios rate: the port layer refuses it
    {"timeout": float("nan")}, {"timeout": float("inf")}, {"timeout": -1}, {"timeout": 0}, {"timeout": 1e300},
    {"timeout": "0.1"}, {"retries": -1}, {"retries": 1.0}, {"retries": 10**9}, {"check": "bogus"},
    {"check": 5}, {"wake_up": 1}, {"echo": "yes"}, {"set_repeats": 0}, {"factory_address": 0},
    {"factory_address": 127}, {"rs485": "kernel"},
])
def test_bad_master_arguments_raise_g485_value_error(pty_link, kwargs: dict) -> None:
    path, _ = pty_link
    t0 = time.monotonic()
    with pytest.raises(G485ValueError):
        G485Master(path, **kwargs)
    assert time.monotonic() - t0 < 5.0


def test_baud_zero_never_blocks(pty_link) -> None:
    path, _ = pty_link
    with pytest.raises(G485ValueError):
        G485Master(path, 0)


@pytest.mark.parametrize("port", [None, 3.5, b"/dev/null\0", [], -1, True])
def test_bad_port_objects(port: Any) -> None:
    with pytest.raises(FapError):
        G485Master(port)


@pytest.mark.parametrize("kwargs", [
    {"bulk_discard_rate": 5.0}, {"bulk_discard_rate": float("nan")}, {"bulk_discard_rate": -0.1},
    {"bulk_discard_rate": "0.5"}, {"seed": 1.5}, {"wake_up_loss": 1}, {"identity": (1, 2, 3)},
    {"identity": (1, 2, 3, 4, 256)}, {"identity": 5}, {"private": {7: ("RW", 0)}}, {"private": {9: ("X", 0)}},
    {"private": {9: ("RW", 300)}}, {"private": {9: 5}}, {"private": [1]}, {"on_apply": 5}, {"eeprom_path": 5},
    {"address": 0}, {"address": 127}, {"address": True}, {"address": 1.0},
])
def test_bad_sim_device_arguments(kwargs: dict) -> None:
    args = {"address": 1, **kwargs}
    address = args.pop("address")
    with pytest.raises(G485ValueError):
        SimDevice(address, **args)


def test_bad_simulator_arguments(pty_link) -> None:
    _, fd = pty_link
    for kwargs in ({"idle_timeout": float("nan")}, {"idle_timeout": -1}, {"baudrate": 0}):
        with pytest.raises(G485ValueError):
            Simulator(fd, [SimDevice(1)], **kwargs)
    with pytest.raises(G485ValueError):
        Simulator(fd, [object()])  # type: ignore[list-item]
    with pytest.raises(G485ValueError):
        Simulator(fd, 5)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def live():
    """A master and a simulated device 1 on a pty pair, shared by the property tests."""
    import os
    import tty

    mfd, sfd = os.openpty()
    tty.setraw(mfd)
    tty.setraw(sfd)
    path = os.ttyname(sfd)
    with Simulator(mfd, [SimDevice(1)]), G485Master(path, 115200, timeout=0.05, retries=0) as master:
        yield master
    os.close(sfd)
    os.close(mfd)


def _only_ours(call: Any) -> None:
    """``call()`` succeeds or raises a FapError; never anything else, never a hang."""
    t0 = time.monotonic()
    try:
        call()
    except FapError:
        pass
    assert time.monotonic() - t0 < 5.0


@FAST
@given(address=junk, register=junk, count=junk)
def test_read_arguments(live, address: Any, register: Any, count: Any) -> None:
    _only_ours(lambda: live.read(address, register, count))


@FAST
@given(address=junk, register=junk, data=junk)
def test_write_arguments(live, address: Any, register: Any, data: Any) -> None:
    _only_ours(lambda: live.write(address, register, data, check="none"))


@FAST
@given(timeout=numbers, retries=junk)
def test_per_call_timeout_and_retries(live, timeout: Any, retries: Any) -> None:
    if isinstance(timeout, (int, float)) and math.isfinite(timeout) and 0 < timeout <= 3600:
        timeout = min(timeout, 0.05)  # a valid timeout: keep the test fast
    if isinstance(retries, int) and not isinstance(retries, bool) and retries > 0:
        retries = 0
    _only_ours(lambda: live.read(1, 7, timeout=timeout, retries=retries))


@FAST
@given(address=junk, command=junk, check=junk, guard=junk)
def test_set_error_word_handshake_arguments(live, address: Any, command: Any, check: Any, guard: Any) -> None:
    _only_ours(lambda: live.set(address, command, check=check, guard=guard))
    _only_ours(lambda: live.error_word(address, check=check))
    _only_ours(lambda: live.handshake(address))
    _only_ours(lambda: live.scan([address], timeout=0.01))


@FAST
@given(writes=junk, repeats=junk)
def test_sync_write_and_helpers(live, writes: Any, repeats: Any) -> None:
    _only_ours(lambda: live.sync_write(writes, apply_repeats=repeats))
    _only_ours(lambda: live.broadcast_set("control_mode", repeats=repeats))
    _only_ours(lambda: live.change_id(1, writes))
    _only_ours(lambda: live.change_id(writes, 2))
    _only_ours(lambda: live.send_raw(writes))


@FAST
@given(value=junk)
def test_codec_functions(value: Any) -> None:
    for fn in (lambda: codec.encode_write(1, 8, value), lambda: codec.encode_read_request(value, 1, 1),
               lambda: codec.encode_read_response(value, [1]), lambda: codec.encode_handshake_response(value),
               lambda: codec.encode_error_word_response(value), lambda: codec.encode_set(1, value),
               lambda: codec.decode_frame(value), lambda: Parser().feed(value)):
        _only_ours(fn)


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=300), cuts=st.lists(st.integers(min_value=0, max_value=300), max_size=8))
def test_parser_same_packets_whole_or_in_chunks(data: bytes, cuts: list) -> None:
    whole = Parser()
    events = whole.feed(data) + whole.expire()
    chunked = Parser()
    got: list = []
    last = 0
    for cut in sorted({c for c in cuts if c <= len(data)}) + [len(data)]:
        got += chunked.feed(data[last:cut])
        last = cut
    got += chunked.expire()
    packets = [e for e in events if isinstance(e, codec.Packet)]
    assert [e for e in got if isinstance(e, codec.Packet)] == packets


def test_closed_master_raises_closed_error(pty_link) -> None:
    from fap_py.errors import ClosedError

    path, _ = pty_link
    master = G485Master(path)
    master.close()
    master.close()  # idempotent
    with pytest.raises(ClosedError):
        master.read(1, 7)


def test_async_front_end_bad_arguments(pty_link) -> None:
    path, fd = pty_link

    async def main() -> None:
        async with AsyncG485Master(path, 115200, timeout=0.05, retries=0) as bus:
            for call in (lambda: bus.read(1, 7, timeout=float("nan")), lambda: bus.read(0, 7),
                         lambda: bus.write(1, 1, "x"), lambda: bus.set(1, "nope"),
                         lambda: bus.scan(5), lambda: bus.read(1, 7, retries=-1)):
                with pytest.raises(G485ValueError):
                    await call()

    with Simulator(fd, [SimDevice(1)]):
        asyncio.run(main())
    with pytest.raises(G485ValueError):
        AsyncG485Master()
    with pytest.raises(G485ValueError):
        AsyncG485Master(path, 0)
