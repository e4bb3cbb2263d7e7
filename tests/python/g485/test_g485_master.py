"""Master against the simulator over a raw pty pair (and over socket:// and loop://)."""
from __future__ import annotations

import logging
import socket
import threading

import pytest
import serial

from fap_py.errors import ClosedError, FapTimeoutError, InvalidValueError
from fap_py.g485 import (
    BroadcastReadError,
    Check,
    DeviceErrorWordError,
    ErrorBit,
    G485Master,
    G485ValueError,
    NoResponseError,
    SetCommand,
    SimDevice,
    Simulator,
    codec,
)

# reply timeouts: generous where no timeout is expected (it never fires, so it costs
# nothing, and a loaded CI machine cannot make it fire), short where one is expected
FAST = 0.5
SHORT = 0.05


@pytest.fixture
def rig(pty_link, tmp_path):
    """Devices 1 and 2 on one simulated port, a master on the other side."""
    path, fd = pty_link
    dev1 = SimDevice(1, eeprom_path=tmp_path / "dev1.json", identity=(11, 7, 1, 2, 3))
    dev2 = SimDevice(2)
    with Simulator(fd, [dev1, dev2]) as sim, G485Master(path, 115200, timeout=FAST) as master:
        yield master, sim, dev1, dev2
    assert sim.error is None


def test_read_write_error_word_handshake_with_every_check(rig):
    master, sim, dev1, dev2 = rig
    for check in Check:
        assert master.read(1, 1, 7, check=check) == bytes((11, 7, 1, 2, 3, 0, 1))
        master.write(2, 8, [9, 8, 7], check=check)
        assert bytes(dev2.registers[8:11]) == b"\x09\x08\x07"
        assert master.read(2, 8, 3, check=check.value) == b"\x09\x08\x07"
        assert master.error_word(1, check=check) == 0
    assert master.read_register(2, 9) == 8
    assert master.handshake(2) == dev2.check_byte
    assert master.stats.retries == 0 and master.stats.ignored_frames == 0


def test_every_set_command_by_name(rig, tmp_path):
    master, sim, dev1, _ = rig
    master.write(1, 8, 5)
    master.set(1, "save_eeprom")
    assert (tmp_path / "dev1.json").exists() and dev1.eeprom[8] == 5
    master.set(1, SetCommand.NON_REAL_TIME_WRITE)
    assert not dev1.real_time
    master.write(1, 9, 6)
    assert dev1.applied[9] == 0
    master.set(1, SetCommand.APPLY_WRITES)
    assert dev1.applied[9] == 6
    master.set(1, SetCommand.REAL_TIME_WRITE)
    assert dev1.real_time
    master.set(1, SetCommand.BULK_MODE)
    assert dev1.bulk_mode
    master.set(1, SetCommand.CONTROL_MODE)
    assert not dev1.bulk_mode
    master.set(1, SetCommand.LOCK_BAUD_RATE)
    assert dev1.baud_locked
    master.write(1, 1, 0, check=Check.NONE)  # read-only: sets an error bit
    assert master.error_word(1) & ErrorBit.READ_ONLY
    with pytest.raises(DeviceErrorWordError, match="READ_ONLY"):
        master.check_error_word(1)
    master.set(1, SetCommand.CLEAR_ERROR_WORD)
    master.check_error_word(1)
    master.write(1, 8, 99)
    master.set(1, SetCommand.RESET)
    assert master.read_register(1, 8) == 5  # back to the EEPROM value
    master.set(1, SetCommand.FACTORY_RESET)
    assert master.read_register(1, 8) == 0 and not dev1.baud_locked
    assert master.stats.retries == 0


def test_set_reread_mode_sends_it_three_times(rig):
    master, sim, dev1, _ = rig
    before = dev1.packets_handled
    master.set(1, SetCommand.CLEAR_ERROR_WORD, check=Check.REREAD)
    master.handshake(1)  # ordered after the three Sets on the same port
    assert dev1.packets_handled - before == 4


def test_broadcast_write_and_set_reach_every_device_without_reply(rig):
    master, sim, dev1, dev2 = rig
    replies = sim.replies_sent
    master.broadcast_write(20, [1, 2])
    master.broadcast_set(SetCommand.BULK_MODE)
    master.write(0, 22, 3)
    master.set(0, "control_mode")
    assert master.read(1, 20, 3) == master.read(2, 20, 3) == b"\x01\x02\x03"  # ordered after the broadcasts
    assert sim.replies_sent - replies == 4  # two reads + two handshakes: nothing for the broadcasts
    assert not dev1.bulk_mode and not dev2.bulk_mode and dev1.packets_handled >= 4
    assert master.stats.ignored_frames == 0


def test_broadcast_read_is_refused(rig):
    master = rig[0]
    for call in (lambda: master.read(0, 1, 1), lambda: master.error_word(0), lambda: master.handshake(0),
                 lambda: master.broadcast_read(1)):
        with pytest.raises(BroadcastReadError, match="cannot be broadcast"):
            call()


@pytest.mark.parametrize("call", [
    lambda m: m.read(127, 1), lambda m: m.read(1, 0), lambda m: m.read(1, 101), lambda m: m.read(1, 95, 10),
    lambda m: m.write(1, 100, [1, 2]), lambda m: m.write(200, 8, 1), lambda m: m.set(1, "nope"),
    lambda m: m.read(1, 1, check="sometimes"), lambda m: m.change_id(1, 127),
])
def test_range_checks_before_anything_is_sent(rig, call):
    master, sim, *_ = rig
    events = sim.events
    with pytest.raises(G485ValueError) as info:
        call(master)
    assert isinstance(info.value, InvalidValueError) and sim.events == events


def test_absent_device_no_response_after_retries(rig):
    master = rig[0]
    with pytest.raises(NoResponseError) as info:
        master.read(9, 1, retries=1, timeout=0.02)
    assert isinstance(info.value, FapTimeoutError) and isinstance(info.value, TimeoutError)
    assert master.stats.no_response == 2 and master.stats.retries == 1
    assert master.read(1, 7) == b"\x01"  # the port still works


def test_sync_write_applies_at_once(rig):
    master, sim, dev1, dev2 = rig
    order = []
    dev1.on_apply = dev2.on_apply = lambda d, first, last: order.append((d.address, first, last))
    master.sync_write([(1, 30, [1, 1]), (2, 30, [2, 2]), (1, 40, 9)])
    master.handshake(1)
    assert order == [(1, 30, 31), (1, 40, 40), (2, 30, 31)]
    assert not dev1.real_time and dev1.pending_writes == {} and dev2.applied[30:32] == b"\x02\x02"
    master.sync_write([(2, 50, 4)], back_to_real_time=True)
    assert dev2.real_time and dev2.applied[50] == 4
    with pytest.raises(G485ValueError):
        master.sync_write([(0, 30, 1)])


def test_change_id_and_save(rig, tmp_path):
    master, sim, dev1, _ = rig
    master.change_id(1, 33, save=True)
    assert dev1.address == 33 and master.read(33, 7) == b"\x21"
    with pytest.raises(NoResponseError):
        master.read(1, 7, retries=0, timeout=0.02)
    assert SimDevice(1, eeprom_path=tmp_path / "dev1.json").address == 33
    master.set(33, SetCommand.NON_REAL_TIME_WRITE)
    with pytest.raises(G485ValueError, match="Non-Real-Time"):
        master.change_id(33, 34)


def test_threads_share_one_master(rig):
    master, sim, dev1, dev2 = rig
    for reg in range(8, 100):
        dev1.set_register(reg, reg)
        dev2.set_register(reg, 255 - reg)
    errors = []

    def worker(n: int) -> None:
        try:
            for i in range(60):
                reg = 8 + (n * 7 + i) % 90
                address = 1 + (i + n) % 2
                want = reg if address == 1 else 255 - reg
                got = master.read(address, reg, 2)
                assert got == bytes((want, want + 1 if address == 1 else want - 1)), (address, reg, got)
                if i % 10 == 0:
                    master.write(address, 100, n)
        except Exception as exc:  # collected, then asserted in the main thread
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(n,)) for n in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert master.stats.retries == 0 and master.stats.transactions == 4 * 66


def test_wake_up_preamble_above_28800_baud(pty_link):
    path, fd = pty_link
    dev = SimDevice(1, wake_up_loss=True)
    with Simulator(fd, [dev]):
        with G485Master(path, 115200, timeout=FAST) as master:
            assert master.wake_up
            master.read(1, 1)
            assert master.stats.retries == 0
            master.set(1, SetCommand.RESET)  # the device detects the baud rate again
            master.read(1, 1)
            assert master.stats.retries == 0
        dev.asleep = True  # power-cycled
        with G485Master(path, 115200, timeout=SHORT, wake_up=False) as master:
            master.read(1, 1)
            assert master.stats.no_response >= 1 and not dev.asleep  # the first packet was lost
        with G485Master(path, 9600, timeout=FAST) as master:
            assert not master.wake_up


def test_frames_logged_at_debug(rig, caplog):
    master = rig[0]
    with caplog.at_level(logging.DEBUG, logger="fap_py.g485"):
        master.read(1, 1, 3, check=Check.NONE)
    text = caplog.text
    assert "ff ff 03 03 01 03 f5" in text and " tx " in text and "rx ff ff ff 05 01 0b 07 01" in text


def test_closed_master(rig):
    master = rig[0]
    master.close()
    with pytest.raises(ClosedError):
        master.read(1, 1)


def test_socket_url_uses_pyserial_generic_path():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    accepted = {}
    t = threading.Thread(target=lambda: accepted.setdefault("conn", server.accept()[0]))
    t.start()
    master = G485Master(f"socket://127.0.0.1:{port}", timeout=0.2)
    t.join()
    conn = accepted["conn"]
    try:
        assert not master._io.fast
        with Simulator(conn.fileno(), [SimDevice(4)]):
            master.write(4, 8, [1, 2])
            assert master.read(4, 8, 2) == b"\x01\x02"
            assert master.error_word(4, check="reread") == 0
    finally:
        master.close()
        conn.close()
        server.close()


def test_loop_url_hears_itself():
    ser = serial.serial_for_url("loop://", timeout=0.01)
    with G485Master(ser, timeout=0.02, retries=0, echo=True) as master:
        master.write(3, 8, [1], check=Check.NONE)  # the echo is read back and compared
        master.broadcast_set(SetCommand.APPLY_WRITES)
    with G485Master(serial.serial_for_url("loop://", timeout=0.01), timeout=0.02, retries=0) as master:
        with pytest.raises(NoResponseError):
            master.read(3, 8)  # its own request is not a reply
        assert master.stats.ignored_frames == 1


def test_bad_constructor_arguments(pty_link):
    path, _ = pty_link
    with pytest.raises(G485ValueError):
        G485Master(path, timeout=0)
    with pytest.raises(G485ValueError):
        G485Master(path, retries=-1)
    with pytest.raises(Exception) as info:
        G485Master("/nonexistent/tty")
    assert isinstance(info.value, OSError)
    with pytest.raises(G485ValueError):
        codec.encode_write(1, 8, "x")  # type: ignore[arg-type]


class Scripted:
    """A fake device on the pty: answers each request with the next scripted bytes."""

    def __init__(self, fd: int, replies: list) -> None:
        self.fd, self.replies, self.requests = fd, list(replies), []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        import os
        import select

        parser = codec.Parser()
        while self.replies:
            if not select.select([self.fd], [], [], 2.0)[0]:
                return
            for ev in parser.feed(os.read(self.fd, 256)):
                if isinstance(ev, codec.Packet):
                    self.requests.append(ev)
                    reply = self.replies.pop(0)
                    if reply:
                        os.write(self.fd, reply)


def test_bad_check_byte_in_reply_is_detected_and_retried(pty_link):
    path, fd = pty_link
    good = codec.encode_read_response(8, b"\x01\x02")
    bad = good[:-1] + bytes((good[-1] ^ 0x01,))
    dev = Scripted(fd, [bad, good])
    with G485Master(path, 9600, timeout=FAST, check=Check.NONE) as master:
        assert master.read(3, 8, 2) == b"\x01\x02"
        assert master.stats.frame_errors == 1 and master.stats.retries == 1
    assert len(dev.requests) == 2


def test_bad_check_byte_without_retries_raises_check_byte_error(pty_link):
    from fap_py.errors import FrameError
    from fap_py.g485 import CheckByteError

    path, fd = pty_link
    good = codec.encode_error_word_response(0x0102)
    Scripted(fd, [good[:5] + b"\x03" + good[6:]])
    with G485Master(path, 9600, timeout=FAST, retries=0) as master:
        with pytest.raises(CheckByteError, match="bad check byte") as info:
            master.error_word(3)
    assert isinstance(info.value, FrameError) and info.value.frame[:3] == b"\xff\xff\xff"


def test_wrong_length_and_stale_replies(pty_link):
    from fap_py.g485 import UnexpectedReplyError

    path, fd = pty_link
    stale = codec.encode_read_response(20, b"\x09")  # valid, but for another request: ignored
    wrong_len = codec.encode_read_response(8, b"\x01\x02\x03")  # the right PID, wrong LENGTH
    Scripted(fd, [stale + codec.encode_read_response(8, b"\x05"), wrong_len])
    with G485Master(path, 9600, timeout=FAST, retries=0, check=Check.NONE) as master:
        assert master.read(3, 8) == b"\x05" and master.stats.ignored_frames == 1
        with pytest.raises(UnexpectedReplyError, match="length byte 5, expected 3"):
            master.read(3, 8)


def test_handshake_mismatch_after_read(pty_link):
    path, fd = pty_link
    reply = codec.encode_read_response(8, b"\x05")
    Scripted(fd, [reply, codec.encode_handshake_response(reply[-1] ^ 0xFF), reply,
                  codec.encode_handshake_response(reply[-1])])
    with G485Master(path, 9600, timeout=FAST) as master:
        assert master.read(3, 8) == b"\x05"
        assert master.stats.check_mismatches == 1


def test_asyncio_front_end(pty_link):
    import asyncio

    from fap_py.g485.aio import AsyncG485Master

    path, fd = pty_link
    dev = SimDevice(6)

    async def main() -> None:
        async with AsyncG485Master(path, 115200, timeout=FAST) as bus:
            await bus.write(6, 8, [4, 5])
            results = await asyncio.gather(*(bus.read(6, 8, 2) for _ in range(10)))
            assert results == [b"\x04\x05"] * 10
            assert await bus.error_word(6) == 0
            await bus.set(6, "save_eeprom")
            assert await bus.handshake(6) == dev.check_byte
            await bus.sync_write([(6, 9, 1)])
            with pytest.raises(NoResponseError):
                await bus.read(7, 1, timeout=0.02, retries=0)

    with Simulator(fd, [dev]):
        asyncio.run(main())
    assert dev.applied[9] == 1


def test_simulator_waits_while_no_master_has_the_pty_open():
    import os
    import time
    import tty

    mfd, sfd = os.openpty()
    tty.setraw(mfd)
    path = os.ttyname(sfd)
    os.close(sfd)  # nobody on the other side: the simulator's fd reports hang-up
    try:
        with Simulator(mfd, [SimDevice(1)]) as sim:
            c0 = time.process_time()
            with G485Master(path, 9600, timeout=FAST) as master:
                assert master.read(1, 7) == b"\x01"
            assert sim.error is None
        assert time.process_time() - c0 < 1.0  # it did not spin
    finally:
        os.close(mfd)


def test_simulator_on_a_pyserial_url_generic_path():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    accepted = {}
    t = threading.Thread(target=lambda: accepted.setdefault("conn", server.accept()[0]))
    t.start()
    sim = Simulator(f"socket://127.0.0.1:{port}", [SimDevice(2)])
    t.join()
    conn = accepted["conn"]
    try:
        assert not sim._io.fast
        with sim, G485Master(conn.fileno(), timeout=FAST) as master:
            master.write(2, 8, [7, 7, 7])
            assert master.read(2, 8, 3) == b"\x07\x07\x07"
            master.set(2, SetCommand.SAVE_EEPROM)
        assert sim.error is None
    finally:
        conn.close()
        server.close()
