"""fap_py.port.Port: the C port layer as a Python object, on real ptys and the virtual bus."""
from __future__ import annotations

import os
import threading
import time
import tty
from collections.abc import Iterator

import pytest

from fap_py.errors import ClosedError, FapError, InvalidValueError, PortError
from fap_py.fap import RS485, RS485Mode
from fap_py.port import MAX_READ, Port, PortBusyError, PortGoneError


@pytest.fixture
def pty() -> Iterator[tuple[int, str]]:
    """A raw pty pair: the far end's fd and the path a Port opens."""
    far, near = os.openpty()
    tty.setraw(far)
    name = os.ttyname(near)
    os.close(near)
    yield far, name
    os.close(far)


def test_write_read_round_trip_and_stats(pty: tuple[int, str]) -> None:
    far, name = pty
    with Port(name, 115200) as port:
        assert port.mode is RS485Mode.NONE  # AUTO on a pty: no kernel RS-485
        assert port.baudrate == 115200 and port.fd >= 0 and port.fileno() == port.fd
        assert port.write(b"\x01\x02\x03") == 3
        assert os.read(far, 16) == b"\x01\x02\x03"
        os.write(far, b"hello")
        assert port.read(16, timeout=1.0) == b"hello"
        st = port.stats
        assert (st.tx_bytes, st.rx_bytes) == (3, 5)
        assert "115200" in repr(port)
    assert port.closed and "closed" in repr(port)


def test_read_deadline_returns_empty(pty: tuple[int, str]) -> None:
    _, name = pty
    with Port(name) as port:
        t0 = time.monotonic()
        assert port.read(8, timeout=0.05) == b""
        assert 0.04 <= time.monotonic() - t0 < 2.0
        assert port.read(8) == b""  # no timeout: do not wait
        assert port.read_until(8, 0) == b""
        assert port.read_until(8, time.monotonic_ns() + 10_000_000) == b""


def test_flush_input_discards(pty: tuple[int, str]) -> None:
    far, name = pty
    with Port(name) as port:
        os.write(far, b"stale")
        deadline = time.monotonic() + 2
        while port.read(1, timeout=0.01) == b"" and time.monotonic() < deadline:
            pass  # until the first byte is there (the rest is queued behind it)
        port.flush_input()
        assert port.read(8, timeout=0.02) == b""


def test_second_opener_is_busy(pty: tuple[int, str]) -> None:
    _, name = pty
    with Port(name):
        with pytest.raises(PortBusyError) as info:
            Port(name)
        assert isinstance(info.value, PortError) and info.value.errno == 16 and "busy" in str(info.value)
    Port(name).close()  # free again after close


def test_non_exclusive_ports_share(pty: tuple[int, str]) -> None:
    _, name = pty
    shared = RS485(exclusive=False)
    with Port(name, rs485=shared), Port(name, rs485=shared):
        pass


def test_explicit_kernel_mode_refused_by_a_pty(pty: tuple[int, str]) -> None:
    _, name = pty
    for mode in (RS485Mode.KERNEL, RS485Mode.SOFT_RTS):
        with pytest.raises(PortError) as info:
            Port(name, rs485=RS485(mode=mode))
        assert info.value.errno == 25  # ENOTTY


@pytest.mark.parametrize("args", [("/nonexistent/tty",), ("",), ("a\0b",)])
def test_bad_paths(args: tuple) -> None:
    with pytest.raises(FapError):
        Port(*args)


@pytest.mark.parametrize("baud", [0, -1, 12345, 2**40, 1.5, "9600", True])
def test_bad_baud(pty: tuple[int, str], baud: object) -> None:
    _, name = pty
    with pytest.raises(InvalidValueError):
        Port(name, baud)  # type: ignore[arg-type]


def test_bad_arguments_and_closed(pty: tuple[int, str]) -> None:
    _, name = pty
    port = Port(name)
    with pytest.raises(InvalidValueError):
        port.write("text")  # type: ignore[arg-type]
    for timeout in (float("nan"), float("inf"), -1, "1"):
        with pytest.raises(InvalidValueError):
            port.read(4, timeout=timeout)  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        port.read("4")  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        port.read_until(MAX_READ + 1, 0)
    for n in (10**9, 0, -5):                    # bounds like read_until (issue 26)
        with pytest.raises(InvalidValueError):
            port.read(n, timeout=0.001)
    with pytest.raises(InvalidValueError):
        Port(name, rs485="soft")  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError):
        Port(5)  # type: ignore[arg-type]
    port.close()
    port.close()
    for call in (lambda: port.write(b"x"), lambda: port.read(1), lambda: port.fd, lambda: port.flush_input(),
                 lambda: port.reopen(), lambda: port.stats, lambda: port.mode):
        with pytest.raises(ClosedError):
            call()


def test_blocking_read_releases_the_gil(pty: tuple[int, str]) -> None:
    """While one thread waits in fap_port_read, another Python thread keeps running."""
    _, name = pty
    counted = 0
    stop = threading.Event()

    def count() -> None:
        nonlocal counted
        while not stop.is_set():
            counted += 1

    with Port(name) as port:
        t = threading.Thread(target=count)
        t.start()
        try:
            before = counted
            assert port.read(1, timeout=0.3) == b""
            during = counted - before
        finally:
            stop.set()
            t.join()
    assert during > 1000


def test_reopen_after_the_device_vanished() -> None:
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2, seed=3) as bus, Port(bus.paths[0]) as port, Port(bus.paths[1]) as other:
        bus.disconnect(0, 0.1)
        with pytest.raises(PortGoneError):
            while True:
                port.read(1, timeout=1.0)
        deadline = time.monotonic() + 10
        while True:
            try:
                port.reopen()
                break
            except PortError:
                assert time.monotonic() < deadline
                time.sleep(0.02)  # polling for the device to come back (it is a separate clock)
        assert port.stats.reopens == 1
        port.write(b"back")
        assert other.read(4, timeout=2.0) == b"back"


def test_echo_suppression_on_an_echo_bus() -> None:
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2, echo=True, seed=3) as bus, \
            Port(bus.paths[0], rs485=RS485(echo_suppression=True)) as port, Port(bus.paths[1]) as other:
        port.write(b"\x10\x20\x30")
        assert other.read(3, timeout=2.0) == b"\x10\x20\x30"
        assert port.read(3, timeout=0.05) == b""  # its own echo was read back and dropped
        assert port.stats.echo_bytes == 3


def test_turnaround_waits_after_the_last_received_byte(pty: tuple[int, str]) -> None:
    far, name = pty
    with Port(name, rs485=RS485(turnaround_us=50_000)) as port:
        os.write(far, b"x")
        assert port.read(1, timeout=1.0) == b"x"
        t0 = time.monotonic()
        port.write(b"y")
        assert time.monotonic() - t0 >= 0.04


def test_close_from_another_thread_ends_a_blocking_read(pty: tuple[int, str]) -> None:
    """Port is a NativeHandle: close() waits for the reader to leave C, never frees under it."""
    _, name = pty
    port = Port(name)
    result: list = []

    def reader() -> None:
        try:
            result.append(port.read(1, timeout=30.0))
        except ClosedError as exc:
            result.append(exc)

    t = threading.Thread(target=reader)
    t.start()
    deadline = time.monotonic() + 5
    while not port._users and time.monotonic() < deadline:  # until the reader is inside C
        time.sleep(0.001)
    t0 = time.monotonic()
    port.close()
    t.join(5)
    assert not t.is_alive() and time.monotonic() - t0 < 2.0
    assert len(result) == 1 and isinstance(result[0], ClosedError)


def _wait_queued(port: Port, far: int, data: bytes) -> None:
    """Write ``data`` from the far end and wait until the port has it queued (not read)."""
    import select

    os.write(far, data)
    p = select.poll()
    p.register(port.fd, select.POLLIN)
    assert p.poll(2000)


def test_transact_discards_stale_input_and_returns_the_reply(pty: tuple[int, str]) -> None:
    far, name = pty
    with Port(name) as port:
        _wait_queued(port, far, b"stale!")

        def answer() -> None:
            got = b""
            while len(got) < 3:
                got += os.read(far, 3 - len(got))
            assert got == b"req"
            os.write(far, b"reply")

        t = threading.Thread(target=answer)
        t.start()
        try:
            reply = port.transact(b"req", 16, time.monotonic_ns() + 2_000_000_000)
        finally:
            t.join()
        while len(reply) < 5:
            reply += port.read(16, timeout=2.0)
        assert reply == b"reply"  # not "stale!": dropped before the request went out
        assert port.transact(b"x", 0, 0) == b""  # no reply awaited
        assert os.read(far, 1) == b"x"
        t0 = time.monotonic()
        assert port.transact(b"y", 4, time.monotonic_ns() + 50_000_000) == b""  # nobody answers
        assert time.monotonic() - t0 >= 0.04
        assert port.transact(memoryview(b"zXz")[::2], 0, 0) == b""  # bytes-like (issue 26)
        got = b""
        while len(got) < 3:
            got += os.read(far, 3 - len(got))
        assert got == b"yzz"                    # the unanswered request, then ours
        for bad in (("x", 1, 0), (b"x", -1, 0), (b"x", MAX_READ + 1, 0), (b"x", 1, -1),
                    (b"x", 1.0, 0)):
            with pytest.raises(InvalidValueError):
                port.transact(*bad)  # type: ignore[arg-type]
    with pytest.raises(ClosedError):
        port.transact(b"x", 1, 0)


def test_close_ends_a_blocked_transact(pty: tuple[int, str]) -> None:
    _, name = pty
    port = Port(name)
    errors: list[BaseException] = []

    def wait() -> None:
        try:
            port.transact(b"q", 8, time.monotonic_ns() + 30_000_000_000)
        except FapError as exc:
            errors.append(exc)

    t = threading.Thread(target=wait)
    t.start()
    time.sleep(0.05)  # let it block (the test passes without it too)
    port.close()
    t.join(5.0)
    assert not t.is_alive()
    assert errors and isinstance(errors[0], ClosedError)


def test_transact_with_echo_suppression() -> None:
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2, echo=True, seed=3) as bus, \
            Port(bus.paths[0], rs485=RS485(echo_suppression=True)) as port, Port(bus.paths[1]) as other:
        assert port.transact(b"\x10\x20", 4, time.monotonic_ns() + 50_000_000) == b""  # echo not a reply
        assert other.read(2, timeout=2.0) == b"\x10\x20"
        assert port.stats.echo_bytes == 2


def test_send_writes_and_checks_its_argument(pty: tuple[int, str]) -> None:
    far, name = pty
    with Port(name) as port:
        assert port.send(b"abc") == 3
        got = b""
        while len(got) < 3:
            got += os.read(far, 3)
        assert got == b"abc"
        assert port.send(bytearray(b"x")) == 1      # bytes-like taken (issue 26)
        with pytest.raises(FapError):
            port.send("x")  # type: ignore[arg-type]
