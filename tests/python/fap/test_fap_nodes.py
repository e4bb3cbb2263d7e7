"""A Python master and three Python slaves on one virtual bus, in one process."""
from __future__ import annotations

import errno
import itertools
import os
import selectors
import threading
import time
from typing import List, Tuple

import pytest
from conftest import FAST, SLAVE_IDS, WAIT, wait_for_event

import fap_py
from fap_py import (
    RS485,
    ClosedError,
    EventKind,
    FapTimeoutError,
    InvalidTypeError,
    InvalidValueError,
    Master,
    Message,
    PortError,
    QueueFullError,
    RS485Mode,
    Slave,
    SlaveExistsError,
    Stats,
    UnknownSlaveError,
)
from fap_py.vbus import VirtualBus

Net = Tuple[Master, List[Slave]]


def test_master_to_each_slave_and_back(net: Net) -> None:
    master, slaves = net
    for s in slaves:
        master.send(f"to {s.id}".encode(), to=s.id)
    for s in slaves:
        assert s.recv(timeout=WAIT) == Message(source=0, data=f"to {s.id}".encode())
    for s in slaves:
        s.send(f"from {s.id}".encode())
    got = {master.recv(timeout=WAIT) for _ in slaves}
    assert got == {Message(s.id, f"from {s.id}".encode()) for s in slaves}
    # DATA for someone else never reaches a node's queue
    assert all(s.recv_nowait() is None for s in slaves)
    assert master.recv_nowait() is None


def test_1024_byte_messages_both_ways(net: Net) -> None:
    master, slaves = net
    big = [bytes((i * 7 + k) & 0xFF for i in range(1024)) for k in range(len(slaves))]
    for s, data in zip(slaves, big):
        master.send(data, to=s.id)
        s.send(bytearray(data[::-1]))
    for s, data in zip(slaves, big):
        msg = s.recv(timeout=WAIT)
        assert msg.source == 0 and msg.data == data and len(msg.data) == 1024
    back = {m.source: m.data for m in (master.recv(timeout=WAIT) for _ in slaves)}
    assert back == {s.id: d[::-1] for s, d in zip(slaves, big)}
    # the engine publishes its counters when a transmit burst ends; flush()
    # returns after that point, so the snapshot holds the 3 DATA frames
    master.flush(timeout=WAIT)
    st = master.stats
    assert st.data_tx == 3 and st.data_rx == 3 and st.crc_errors == 0


def test_slave_to_slave(net: Net) -> None:
    _, (a, b, c) = net
    a.send(memoryview(b"a->c"), to=c.id)
    c.send(b"c->b", to=b.id)
    assert c.recv(timeout=WAIT) == Message(a.id, b"a->c")
    assert b.recv(timeout=WAIT) == Message(c.id, b"c->b")


def test_many_messages_keep_order(net: Net) -> None:
    master, (a, _, _) = net
    for i in range(200):
        while True:
            try:
                master.send(i.to_bytes(2, "little"), to=a.id)
                break
            except QueueFullError:
                master.flush(timeout=WAIT)
    got = [int.from_bytes(a.recv(timeout=WAIT).data, "little") for _ in range(200)]
    assert got == list(range(200))


def test_iteration_and_messages(net: Net) -> None:
    master, slaves = net
    for s in slaves:
        s.send(bytes([s.id]))
    got = sorted(m.source for m in itertools.islice(master.messages(timeout=WAIT), 3))
    assert got == sorted(SLAVE_IDS)
    assert list(master.messages(timeout=0.05)) == []       # ends after a quiet 50 ms
    # plain iteration ends when another thread closes the node
    s = slaves[0]
    master.send(b"one", to=s.id)
    seen: List[Message] = []

    def consume() -> None:
        for msg in s:
            seen.append(msg)
            s.close()

    t = threading.Thread(target=consume)
    t.start()
    t.join(WAIT)
    assert not t.is_alive() and seen == [Message(0, b"one")]


def test_slave_disappears_and_returns(bus: VirtualBus) -> None:
    with Master(bus.paths[0], slaves=SLAVE_IDS, **FAST) as master:
        slaves = [Slave(p, id=i) for p, i in zip(bus.paths[1:], SLAVE_IDS)]
        try:
            master.wait_active(timeout=WAIT)
            list(master.events())                      # the joins so far
            gone = slaves[1]
            gone.close()
            wait_for_event(master, EventKind.SLAVE_INACTIVE, gone.id)
            assert gone.id not in master.active_slaves and not master.is_active(gone.id)
            assert gone.id in master.slaves
            # the others still talk while it is away
            master.send(b"still here?", to=slaves[0].id)
            assert slaves[0].recv(timeout=WAIT).data == b"still here?"
            # ... and the master keeps querying it (ID cycles every 50 ms)
            wait_for_event(master, EventKind.ID_TIMEOUT, gone.id)
            back = Slave(bus.paths[2], id=gone.id)
            slaves[1] = back
            master.wait_active([gone.id], timeout=WAIT)
            wait_for_event(master, EventKind.SLAVE_ACTIVE, gone.id)   # kept by wait_active
            master.send(b"welcome back", to=gone.id)
            assert back.recv(timeout=WAIT) == Message(0, b"welcome back")
            back.send(b"thanks")
            assert master.recv(timeout=WAIT) == Message(gone.id, b"thanks")
            st = master.stats
            assert st.data_done_timeouts >= 1 and st.id_timeouts >= 1 and st.id_cycles >= 2
        finally:
            for s in slaves:
                s.close()


def test_slave_sees_queries(net: Net) -> None:
    _, slaves = net
    ev = slaves[0].wait_event(timeout=WAIT)
    assert ev.kind is EventKind.QUERIED and ev.id == slaves[0].id
    assert ev.name == "queried" and str(ev) == f"queried id={slaves[0].id}"
    assert 0 < ev.time_ns <= time.monotonic_ns()


def test_add_and_remove_slaves(bus: VirtualBus) -> None:
    with Master(bus.paths[0], **FAST) as master, Slave(bus.paths[1], id=5) as s5:
        assert master.slaves == [] and master.active_slaves == []
        master.add_slave(5)
        assert master.slaves == [5]
        with pytest.raises(SlaveExistsError, match="already listed"):
            master.add_slave(5)
        master.wait_active([5], timeout=WAIT)
        assert master.active_slaves == [5] and master.is_active(5)
        master.remove_slave(5)
        assert master.slaves == [] and master.active_slaves == []
        with pytest.raises(UnknownSlaveError, match="not listed"):
            master.remove_slave(5)
        with pytest.raises(UnknownSlaveError):
            master.is_active(5)
        # listed again: queried afresh, then polled
        master.add_slave(5)
        master.wait_active([5], timeout=WAIT)
        s5.send(b"again")
        assert master.recv(timeout=WAIT) == Message(5, b"again")


def test_wait_active_timeout_names_missing(bus: VirtualBus) -> None:
    with Master(bus.paths[0], slaves=[9], **FAST) as master:
        # 2 s: ID cycles of 0.1 s, so ID timeouts happen inside the wait even on a loaded
        # machine (0.2 s once saw none under load 8); they are what the wait must keep
        with pytest.raises(FapTimeoutError, match=r"\[9\]"):
            master.wait_active(timeout=2.0)
        kinds = {e.kind for e in master.events()}
        assert kinds == {EventKind.ID_TIMEOUT}       # kept for the user


@pytest.mark.direct_only("it reads the engine's notification fd (fileno), which a daemon client does not have")
def test_stats_and_info(net: Net) -> None:
    master, slaves = net
    master.send(b"ping", to=slaves[0].id)
    slaves[0].recv(timeout=WAIT)
    slaves[0].send(b"pong")
    master.recv(timeout=WAIT)
    # the pong is delivered on its DATA frame; the poll it came in is counted at the
    # DATA_DONE that follows, which a loaded machine may not have read yet
    deadline = time.monotonic() + WAIT
    while (master.stats.polls == 0 or master.stats.cycles == 0) and time.monotonic() < deadline:
        time.sleep(0.005)
    st = master.stats
    assert isinstance(st, Stats)
    assert st.frames_tx > 0 and st.frames_rx > 0 and st.polls > 0 and st.cycles > 0
    assert st.as_dict()["frames_tx"] == st.frames_tx
    assert master.rs485_mode is RS485Mode.NONE       # AUTO on a pty falls back to NONE
    assert master.tx_pending == 0 and master.rx_pending == 0
    assert isinstance(master.fileno(), int) and master.fileno() >= 0
    assert "Master" in repr(master) and "open" in repr(master)
    assert slaves[0].path == slaves[0].path and slaves[0].id == SLAVE_IDS[0]


def test_queue_full_raises_and_keeps_what_was_queued(bus: VirtualBus) -> None:
    # a slave is never polled without an active master: its queue fills
    with Slave(bus.paths[1], id=4, tx_queue=2) as s:
        s.send(b"1")
        s.send(b"2")
        with pytest.raises(QueueFullError):
            s.send(b"3")
        assert s.tx_pending == 2
        with pytest.raises(QueueFullError):
            s.send(b"3", timeout=0.05)           # waited for room, none came
        with pytest.raises(FapTimeoutError):
            s.flush(timeout=0.05)
        with Master(bus.paths[0], slaves=[4], **FAST) as master:
            s.send(b"3", timeout=WAIT)           # room comes when the master polls
            assert [master.recv(timeout=WAIT).data for _ in range(3)] == [b"1", b"2", b"3"]
            s.flush(timeout=WAIT)
            assert s.tx_pending == 0


@pytest.mark.parametrize("bad, exc", [
    (0, InvalidValueError), (32, InvalidValueError), (-1, InvalidValueError),
    ("7", InvalidTypeError), (7.0, InvalidTypeError), (True, InvalidTypeError),
])
def test_bad_destination_raises_before_c(net: Net, bad: object, exc: type) -> None:
    master, _ = net
    before = master.stats.data_tx
    with pytest.raises(exc):
        master.send(b"x", to=bad)  # type: ignore[arg-type]
    with pytest.raises(exc):
        master.add_slave(bad)  # type: ignore[arg-type]
    assert master.stats.data_tx == before and master.tx_pending == 0


def test_bad_data_raises_before_c(net: Net) -> None:
    master, (s, _, _) = net
    with pytest.raises(InvalidValueError, match="1..1024"):
        master.send(bytes(1025), to=s.id)
    with pytest.raises(InvalidValueError, match="1..1024"):
        master.send(b"", to=s.id)
    with pytest.raises(InvalidTypeError, match="encode"):
        master.send("text", to=s.id)  # type: ignore[arg-type]
    with pytest.raises(InvalidTypeError):
        master.send([1, 2], to=s.id)  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError, match="own ID"):
        s.send(b"me", to=s.id)
    with pytest.raises(InvalidValueError):
        master.recv(timeout=-1)
    assert issubclass(InvalidTypeError, TypeError) and issubclass(InvalidTypeError, ValueError)
    assert master.tx_pending == 0 and s.tx_pending == 0


def test_bad_constructor_arguments(bus: VirtualBus) -> None:
    p = bus.paths[0]
    with pytest.raises(InvalidValueError):
        Slave(p, id=0)
    with pytest.raises(InvalidValueError):
        Slave(p, id=32)
    with pytest.raises(InvalidTypeError):
        Slave(p, id="3")  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        Master(p, slaves=[1, 1])
    with pytest.raises(InvalidValueError):
        Master(p, slaves=[0])
    with pytest.raises(InvalidTypeError):
        Master(p, slaves=5)  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        Master(p, 0)
    with pytest.raises(InvalidValueError):
        Master(p, id_cycle=-1)
    with pytest.raises(InvalidTypeError):
        Master(p, rs485="none")  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        RS485(mode=9)  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        RS485(turnaround_us=-5)
    with pytest.raises(TypeError):
        Master(p, bogus=1)  # type: ignore[call-arg]
    # nothing was left open: the port is still free for an exclusive open
    with Master(p) as m:
        assert m.slaves == []


def test_port_errors_carry_errno_and_path(bus: VirtualBus, tmp_path) -> None:
    missing = str(tmp_path / "no-such-tty")
    with pytest.raises(PortError) as ei:
        Master(missing)
    assert ei.value.errno == errno.ENOENT and ei.value.path == missing
    assert isinstance(ei.value, OSError) and isinstance(ei.value, fap_py.FapError)
    # a pty has no kernel RS-485: asking for it explicitly fails clearly
    with pytest.raises(PortError) as ei:
        Slave(bus.paths[1], id=2, rs485=RS485(mode=RS485Mode.KERNEL))
    assert ei.value.errno == errno.ENOTTY
    # exclusive by default: a second opener of the same port is refused
    with Slave(bus.paths[1], id=2):
        with pytest.raises(PortError) as ei:
            Slave(bus.paths[1], id=3)
        assert ei.value.errno == errno.EBUSY


def test_rs485_options_reach_the_port_layer(bus: VirtualBus) -> None:
    opts = RS485(mode=RS485Mode.NONE, turnaround_us=2000, echo_suppression=False,
                 delay_before_send_us=100, delay_after_send_us=100, rts_active_high=False)
    with Master(bus.paths[0], 57600, slaves=[2], rs485=opts, **FAST) as m, \
         Slave(bus.paths[1], 57600, id=2, rs485=RS485(mode=RS485Mode.NONE)) as s:
        assert m.rs485_mode is RS485Mode.NONE and m.rs485 == opts and m.baudrate == 57600
        m.wait_active(timeout=WAIT)
        s.send(b"with turnaround")
        assert m.recv(timeout=WAIT).data == b"with turnaround"
    with pytest.raises(PortError) as ei:   # SOFT_RTS needs the RTS ioctl: none on a pty
        Master(bus.paths[0], rs485=RS485(mode=RS485Mode.SOFT_RTS))
    assert ei.value.errno == errno.ENOTTY


def test_closed_node_raises_closed_error(bus: VirtualBus) -> None:
    m = Master(bus.paths[0], slaves=[1])
    m.close()
    m.close()                                  # idempotent
    assert m.closed and "closed" in repr(m)
    for call in (lambda: m.send(b"x", to=1), lambda: m.recv(timeout=0), lambda: m.stats,
                 lambda: m.add_slave(2), lambda: m.active_slaves, m.fileno,
                 lambda: m.wait_event(0)):
        with pytest.raises(ClosedError):
            call()
    assert list(m.events()) == [] and list(m) == []


def test_close_wakes_a_blocked_recv(bus: VirtualBus) -> None:
    s = Slave(bus.paths[1], id=1)
    started = threading.Event()
    result: List[BaseException] = []

    def blocked() -> None:
        started.set()
        try:
            s.recv()                             # no timeout: waits until close
        except BaseException as exc:
            result.append(exc)

    t = threading.Thread(target=blocked)
    t.start()
    started.wait(WAIT)
    s.close()
    t.join(WAIT)
    assert not t.is_alive() and len(result) == 1 and isinstance(result[0], ClosedError)


def test_blocking_recv_releases_the_gil(bus: VirtualBus) -> None:
    with Slave(bus.paths[1], id=1) as s:
        waiting = threading.Event()

        def blocked() -> None:
            waiting.set()
            with pytest.raises((FapTimeoutError, ClosedError)):
                s.recv(timeout=3.0)

        t = threading.Thread(target=blocked)
        t.start()
        waiting.wait(WAIT)
        # Pure-Python work in this thread runs while the other one waits in C:
        # with the GIL held there, this loop could only finish after recv's 3 s.
        t0 = time.monotonic()
        total = sum(i * i for i in range(300_000))
        spent = time.monotonic() - t0
        assert total > 0 and t.is_alive(), f"loop took {spent:.2f} s"
        s.close()                     # ends the wait early (ClosedError in the thread)
        t.join(WAIT)


def test_node_is_context_manager_and_exports() -> None:
    for name in ("Master", "Slave", "Message", "SlaveEvent", "Stats", "RS485", "RS485Mode",
                 "EventKind", "NotMasterError", "SlaveExistsError", "UnknownSlaveError"):
        assert name in fap_py.__all__ and hasattr(fap_py, name)
    assert issubclass(fap_py.UnknownSlaveError, InvalidValueError)
    assert os.path.exists(os.path.join(os.path.dirname(fap_py.__file__), "py.typed"))


@pytest.mark.direct_only("the engine's own event thread and notification fd belong to the port's own master")
def test_events_are_read_by_python_threads_not_from_the_engine(net: Net) -> None:
    """Slave state changes reach Python through the event queue, in the reader's thread."""
    master, (a, _, _) = net
    list(master.events())
    seen: List[Tuple[str, EventKind, int]] = []

    def reader() -> None:
        while True:
            ev = master.wait_event(timeout=WAIT)
            seen.append((threading.current_thread().name, ev.kind, ev.id))
            if ev.kind is EventKind.SLAVE_INACTIVE and ev.id == a.id:
                return

    t = threading.Thread(target=reader, name="event-reader")
    t.start()
    a.close()                             # -> SLAVE_INACTIVE for a
    t.join(WAIT)
    assert not t.is_alive()
    assert seen[-1] == ("event-reader", EventKind.SLAVE_INACTIVE, a.id)
    assert {name for name, _, _ in seen} == {"event-reader"}


@pytest.mark.direct_only("the engine's notification fd (fileno) belongs to the port's own master; a daemon client has a socket")
def test_notify_fd_works_with_selectors(net: Net) -> None:
    master, (a, _, _) = net
    list(master.events())
    with selectors.DefaultSelector() as sel:
        sel.register(master.fileno(), selectors.EVENT_READ)
        a.send(b"select me")
        assert sel.select(timeout=WAIT), "notify fd never became readable"
        assert master.recv_nowait() == Message(a.id, b"select me")
        list(master.events())                 # drain events too: the fd is level-triggered
        if sel.select(timeout=0):             # only if something new came meanwhile
            assert master.rx_pending or list(master.events())


def test_port_lost_and_reopened_events(bus: VirtualBus) -> None:
    with Master(bus.paths[0], slaves=[2], **FAST) as master, \
            Slave(bus.paths[1], id=2, reopen_interval=0.02) as s:
        master.wait_active(timeout=WAIT)
        bus.disconnect(1, 0.1)                # the slave's device vanishes for 100 ms
        wait_for_event(s, EventKind.PORT_LOST, 2)
        wait_for_event(s, EventKind.PORT_REOPENED, 2)
        master.wait_active([2], timeout=WAIT)
        s.send(b"back on the wire")
        assert master.recv(timeout=WAIT) == Message(2, b"back on the wire")
        st = s.stats
        assert st.port_lost >= 1 and st.port_reopened >= 1


def test_unsupported_baud_rate_is_invalid_value(bus: VirtualBus) -> None:
    with pytest.raises(InvalidValueError):
        Master(bus.paths[0], 12345)
