"""The vendor API (fap.h), declared in fap.cdef, reached from Python through cffi.

It runs over the same engine as Master/Slave: a classic-API master here talks
to a fap_py.Slave on the same virtual bus.
"""
from __future__ import annotations

import select
import time
from typing import Iterator

import pytest
from conftest import WAIT

from fap_py import InvalidValueError, Message, NotInitialisedError, Slave
from fap_py._native import ffi, lib
from fap_py.fap import classic_check
from fap_py.vbus import VirtualBus


@pytest.fixture
def classic() -> Iterator[None]:
    yield
    lib.fapClassicClose()           # the process-wide default handle


def test_classic_master_talks_to_a_python_slave(bus: VirtualBus, classic: None) -> None:
    opts = ffi.new("fapx_options *")
    lib.fapx_options_init(opts)
    opts.idc_us = 50_000                        # ID cycle 50 ms instead of 15 s
    lib.fapClassicSetOptions(opts)
    assert lib.fapTx(b"x", 1, 1) == lib.E_INIT  # nothing initialised yet
    with pytest.raises(NotInitialisedError, match="E_INIT"):
        classic_check(lib.fapTx(b"x", 1, 1), "fapTx")
    with Slave(bus.paths[1], 115200, id=4) as slave:
        assert lib.fapInit(bus.paths[0].encode(), 115200) == lib.GOOD
        cfg = ffi.new("fapT *", {"id": 0, "mode": lib.FAP_MASTER, "idcTime": 0})
        assert lib.fapConfig(cfg) == lib.GOOD
        assert lib.fapAddSlave(4) == lib.GOOD
        assert lib.fapAddSlave(4) == lib.E_VALUE
        with pytest.raises(InvalidValueError, match="E_VALUE"):
            classic_check(lib.fapAddSlave(4), "fapAddSlave")
        assert lib.fapClassicHandle() != ffi.NULL
        data = bytes(range(200))
        classic_check(lib.fapTx(data, len(data), 4), "fapTx")
        assert slave.recv(timeout=WAIT) == Message(0, data)
        slave.send(b"vendor API works")
        buf = ffi.new("u8[]", lib.MAX_DATA_SIZE)
        size, src = ffi.new("usys *"), ffi.new("usys *")
        h = lib.fapClassicHandle()
        fd = lib.fapx_notify_fd(h)     # readable while a frame or an event is queued
        ev = ffi.new("fapx_event *")
        deadline = time.monotonic() + WAIT
        while lib.fapRx(buf, size, src) == lib.E_RES:   # fapRx never blocks
            while lib.fapx_event_get(h, ev) == 0:        # events keep the fd readable
                pass
            assert select.select([fd], [], [], max(0.0, deadline - time.monotonic()))[0]
        assert (ffi.buffer(buf, size[0])[:], src[0]) == (b"vendor API works", 4)
