"""NativeHandle, the one lifetime rule of every C-handle owner, under abuse:
concurrent close, close during a blocking call, forgotten objects."""
from __future__ import annotations

import gc
import threading
import time
from typing import Any, Callable, List

import pytest

from fap_py import execasync, fap, mikroc
from fap_py._handle import NativeHandle
from fap_py.errors import ClosedError
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus

pytestmark = pytest.mark.timeout(60)
LINE = RS485(mode=RS485Mode.NONE)

OPENERS: List[Callable[[str], Any]] = [
    lambda p: fap.Master(p, rs485=LINE),
    lambda p: fap.Slave(p, id=4, rs485=LINE),
    lambda p: execasync.Master(p, rs485=LINE),
    lambda p: execasync.Slave(p, node=4, handler=bytes, rs485=LINE),
    lambda p: mikroc.Master(p, rs485=LINE),
    lambda p: mikroc.Slave(p, address=4, rs485=LINE),
]


def test_every_owner_is_a_native_handle_and_closes_once_from_many_threads() -> None:
    with VirtualBus(ports=2) as bus:
        assert isinstance(bus, NativeHandle)
        for open_ in OPENERS:
            obj = open_(bus.paths[0])
            assert isinstance(obj, NativeHandle) and not obj.closed
            threads = [threading.Thread(target=obj.close) for _ in range(8)]
            for t in threads:
                t.start()
            for t in threads:
                t.join(10)
            assert obj.closed and not any(t.is_alive() for t in threads)
            with pytest.raises(ClosedError):
                obj.fileno()


def test_forgotten_objects_release_their_port() -> None:
    # exclusive ports: a second opener fails while the first lives, works once it is collected
    with VirtualBus(ports=2) as bus:
        for open_ in OPENERS:
            obj = open_(bus.paths[0])
            del obj
            gc.collect()
            again = open_(bus.paths[0])        # PortError (EBUSY) if the first leaked
            again.close()


def test_close_from_another_thread_ends_blocking_calls() -> None:
    with VirtualBus(ports=2) as bus:
        calls = [
            (lambda p: fap.Slave(p, id=4, rs485=LINE), lambda o: o.recv(timeout=None)),
            (lambda p: execasync.Slave(p, node=4, handler=bytes, rs485=LINE), lambda o: o.serve(None)),
            (lambda p: mikroc.Slave(p, address=4, rs485=LINE), lambda o: o.receive(timeout=None)),
        ]
        for open_, block in calls:
            obj = open_(bus.paths[0])
            got: List[BaseException] = []

            def run(obj: Any = obj, block: Callable[[Any], Any] = block) -> None:
                try:
                    block(obj)
                except BaseException as exc:  # recorded for the assert
                    got.append(exc)

            t = threading.Thread(target=run)
            t.start()
            time.sleep(0.05)         # let it enter C; the assert below does not depend on it
            obj.close()
            t.join(5)
            assert not t.is_alive(), obj
            assert len(got) == 1 and isinstance(got[0], ClosedError), (obj, got)
