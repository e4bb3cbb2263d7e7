"""Master and simulators on the virtual bus: several ports, broadcast, faults and retries.

Port 0: the master; port 1: devices 1 and 2; port 2: device 3.
"""
from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest

sys.path.append(str(Path(__file__).resolve().parents[1] / "serve"))  # last: never shadows a conftest
from serve_helpers import start_daemon  # the daemon tests' own starter

from fap_py.errors import FapError
from fap_py.g485 import (
    Check,
    ErrorBit,
    G485Error,
    G485Master,
    HandshakeMismatchError,
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


@pytest.fixture(params=["direct", "daemon"])
def net(request, vbus, tmp_path):
    """Each test twice: the master on port 0 itself, and through ``fap serve --protocol
    g485`` on it (``fapd://``: the same calls, results and exceptions; a test that needs
    the port's own master is marked ``direct_only`` with why)."""
    devs = [SimDevice(1, eeprom_path=tmp_path / "d1.json"), SimDevice(2), SimDevice(3)]
    daemon = None
    if request.param == "daemon":
        daemon = start_daemon(str(tmp_path), vbus.paths[0], "--timeout", str(FAST), "--retries", "3",
                              protocol="g485")
    try:
        with Simulator(vbus.paths[1], devs[:2]) as sim1, Simulator(vbus.paths[2], devs[2:]) as sim2, \
                G485Master(daemon.url if daemon else vbus.paths[0], 115200, timeout=FAST,
                           retries=3) as master:
            yield master, vbus, devs, (sim1, sim2)
    finally:
        if daemon is not None:
            daemon.stop()
    assert sim1.error is None and sim2.error is None


def test_every_transaction_over_the_bus(net):
    master, bus, (d1, d2, d3), sims = net
    for address in (1, 2, 3):
        master.write(address, 8, [address, 0x10 + address])
        assert master.read(address, 7, 3) == bytes((address, address, 0x10 + address))
        assert master.error_word(address) == 0
        assert master.handshake(address) == master.believed_check_byte(address)
        for cmd in SetCommand:
            if cmd not in (SetCommand.RESET, SetCommand.FACTORY_RESET):
                master.set(address, cmd.name)
    master.set(3, SetCommand.CONTROL_MODE)  # the loop left bulk and non-real-time modes on
    master.set(3, SetCommand.REAL_TIME_WRITE)
    master.write(3, 7, 30)  # ID 3 -> 30, then reset: the unsaved ID change is undone, so
    master.set(30, SetCommand.RESET, check=Check.NONE)  # nobody could answer a handshake at 30
    assert master.read(3, 7) == b"\x03"
    master.change_id(3, 31, save=True)
    master.set(31, SetCommand.FACTORY_RESET, factory_address=3)  # back to its factory ID
    assert master.read(3, 7) == b"\x03" and d3.address == 3
    assert master.stats.retries == 0 and master.stats.ignored_frames == 0
    assert sims[1].replies_sent > 0 and d3.packets_handled > 0


def test_broadcast_reaches_devices_on_every_port_and_nobody_answers(net):
    master, bus, devs, (sim1, sim2) = net
    master.broadcast_write(60, [5, 6, 7])
    master.broadcast_set(SetCommand.NON_REAL_TIME_WRITE)
    master.broadcast_write(63, 8)
    master.broadcast_set(SetCommand.APPLY_WRITES)
    for address in (1, 2, 3):  # each read is ordered after the broadcasts on its port
        assert master.read(address, 60, 4) == b"\x05\x06\x07\x08"
    assert all(d.applied[63] == 8 and not d.real_time for d in devs)
    assert sim1.replies_sent + sim2.replies_sent == 6  # 3 reads + 3 handshakes
    assert master.stats.ignored_frames == 0


def test_sync_write_across_ports(net):
    master, bus, (d1, d2, d3), _ = net
    master.sync_write([(1, 20, 1), (3, 20, 3)], back_to_real_time=True)
    assert d1.applied[20] == 1 and d3.applied[20] == 3 and d1.real_time and d3.real_time


def test_corrupted_reply_is_detected_and_retried(net):
    master, bus, (d1, _, _), _ = net
    master.timeout = SHORT
    master.write(1, 8, [1, 2, 3, 4])
    for n in (1, 2, 9, 16):
        before = master.stats.frame_errors + master.stats.no_response
        bus.corrupt_next(1, n)  # bit errors in the simulator's next reply
        assert master.read(1, 8, 4) == b"\x01\x02\x03\x04"
        assert master.stats.frame_errors + master.stats.no_response > before, n
    assert bus.stats.bit_errors == 1 + 2 + 9 + 16


def test_dropped_reply_and_dropped_request_are_retried(net):
    master, bus, _, _ = net
    master.timeout = SHORT
    bus.drop_next(1, 9)  # the read response vanishes
    assert master.read(1, 1, 3) == b"\x0b\x01\x01"
    assert master.stats.no_response == 1
    bus.drop_next(0, 7)  # the write vanishes: the handshake returns an old check byte
    master.write(2, 9, 2)
    assert master.stats.check_mismatches == 1 and master.read(2, 9) == b"\x02"
    bus.drop_next(0, 6)  # a handshake request vanishes
    assert master.handshake(2) == master.believed_check_byte(2)
    assert master.stats.no_response == 2


def test_without_retries_errors_reach_the_caller(net):
    master, bus, _, _ = net
    master.timeout = SHORT
    bus.drop_next(1, 9)
    with pytest.raises(NoResponseError):
        master.read(1, 1, 3, retries=0)
    bus.corrupt_next(1, 9)
    with pytest.raises(G485Error):
        master.read(1, 1, 3, retries=0)


def test_seeded_bit_errors_on_replies_every_read_still_right(net):
    master, bus, (d1, d2, _), _ = net
    for reg in range(8, 101):
        d1.set_register(reg, reg)
    master.timeout = SHORT
    master.retries = 8
    bus.set_fault(port=1, bit_error_rate=0.01)
    for i in range(150):
        reg = 8 + i % 90
        assert master.read(1, reg, 4 if reg <= 97 else 1)[0] == reg
    bus.set_fault(port=1, bit_error_rate=0.0)
    stats = master.stats
    assert bus.stats.bit_errors > 0
    assert stats.retries > 0 and stats.frame_errors + stats.no_response + stats.check_mismatches > 0


def test_seeded_bit_errors_both_ways_writes_land(net):
    master, bus, (d1, _, _), _ = net
    master.timeout = SHORT
    master.retries = 10
    bus.set_fault(port=None, bit_error_rate=0.005)
    for i in range(60):
        master.write(1, 30 + i % 20, i)
        assert master.read(1, 30 + i % 20) == bytes((i,))
    bus.set_fault(port=None, bit_error_rate=0.0)
    master.set(1, SetCommand.CLEAR_ERROR_WORD)
    assert master.error_word(1) == 0
    assert bus.stats.bit_errors > 0


def test_handshake_weakness_lost_set_passes_unless_guarded(net):
    master, bus, (d1, _, _), _ = net
    master.set(1, SetCommand.SAVE_EEPROM)  # device check byte == this Set's MDOC now
    d1.set_register(8, 42)  # something new to save (no bus traffic)
    bus.drop_next(0, 6)  # the next Set never arrives
    master.set(1, SetCommand.SAVE_EEPROM, guard=False)
    assert master.stats.check_mismatches == 0  # the handshake "confirmed" it ...
    assert d1.eeprom[8] == 0  # ... but nothing was saved: the seed's weakness
    # the remedy: a read first, so the device's check byte differs from the Set's
    master.read(1, 1, check=Check.NONE)
    bus.drop_next(0, 6)
    master.set(1, SetCommand.SAVE_EEPROM, guard=False)
    assert master.stats.check_mismatches == 1 and d1.eeprom[8] == 42
    # set_guard (the default) does that read by itself when needed
    before = d1.packets_handled
    master.set(1, SetCommand.SAVE_EEPROM)
    assert d1.packets_handled - before == 3  # guard read, Set, handshake


def test_handshake_mismatch_raised_when_retries_exhausted(net):
    master, bus, _, _ = net
    master.read(1, 1, check=Check.NONE)
    bus.drop_next(0, 6)
    with pytest.raises(HandshakeMismatchError) as info:
        master.set(1, SetCommand.CLEAR_ERROR_WORD, retries=0)
    assert info.value.expected != info.value.got and isinstance(info.value, FapError)


def test_bad_request_sets_error_bits(net):
    master, bus, (d1, _, _), _ = net
    master.timeout = SHORT
    master.read(1, 1)  # the first packet carried the wake-up preamble
    bus.corrupt_next(0, 1)  # the request's first byte: the device never sees a packet
    with pytest.raises(G485Error):
        master.read(1, 1, retries=0)
    bad = bytearray(codec.encode_write(1, 8, 1))
    bad[-1] ^= 0x04
    master.send_raw(bytes(bad))  # a write with a wrong check byte: not executed
    master.write(1, 2, 1, check=Check.NONE)  # read-only register
    word = master.error_word(1)
    assert word == ErrorBit.BAD_CHECK | ErrorBit.READ_ONLY and d1.registers[8] == 0
    master.set(1, SetCommand.CLEAR_ERROR_WORD)
    assert master.error_word(1) == 0


def test_bulk_mode_discards_are_retried(net):
    master, bus, (d1, _, _), _ = net
    master.timeout = SHORT
    master.retries = 10
    master.set(1, SetCommand.BULK_MODE)
    for _ in range(30):
        assert master.read(1, 7) == b"\x01"
    assert d1.discarded_in_bulk > 0 and master.stats.no_response >= d1.discarded_in_bulk
    master.set(1, SetCommand.CONTROL_MODE)


def test_threads_hammer_one_master_on_the_bus(net):
    master, bus, devs, _ = net
    for d in devs:
        for reg in range(8, 101):
            d.set_register(reg, (reg * d.address) & 0xFF)
    errors = []

    def worker(n: int) -> None:
        try:
            for i in range(40):
                address = 1 + (n + i) % 3
                reg = 8 + (i * 13 + n) % 90
                assert master.read(address, reg) == bytes(((reg * address) & 0xFF,))
        except Exception as exc:  # collected, then asserted in the main thread
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(n,)) for n in range(5)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and master.stats.retries == 0


def test_echo_bus_master_reads_back_its_frames(tmp_path):
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2, echo=True, seed=3) as bus, \
            Simulator(bus.paths[1], [SimDevice(5)]) as sim, \
            G485Master(bus.paths[0], timeout=FAST, echo=True) as master:
        master.write(5, 8, [1, 2])
        assert master.read(5, 8, 2) == b"\x01\x02"
        assert master.error_word(5) == 0
        master.broadcast_set(SetCommand.CLEAR_ERROR_WORD)
        assert master.stats.retries == 0
        assert sim.error is None


def test_paced_bus_reply_timeout_includes_wire_time():
    """At 19200 baud a 106-byte reply takes 55 ms on the wire: a 50 ms timeout must still wait for it."""
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2, baud=19200, seed=5) as bus, \
            Simulator(bus.paths[1], [SimDevice(8)]) as sim, \
            G485Master(bus.paths[0], 19200, timeout=SHORT, retries=0) as master:
        assert not master.wake_up
        data = master.read(8, 1, 100, check=Check.NONE)
        assert len(data) == 100 and data[6] == 8
        assert sim.error is None


def test_simulator_port_disconnect_and_return(net):
    master, bus, _, (sim1, _) = net
    master.timeout = SHORT
    master.read(1, 7)
    bus.disconnect(1, 0.1)  # the simulator's port hangs up, then comes back at the same path
    assert master.read(1, 7, retries=20) == b"\x01"
    assert sim1.reopened == 1 and sim1.error is None


def test_master_port_disconnect_raises_port_error(net):
    from fap_py.errors import PortError

    master, bus, _, _ = net
    master.read(1, 7)
    bus.disconnect(0, 0.1)
    with pytest.raises(PortError):
        master.read(1, 7)


def test_master_and_simulator_take_rs485_line_options(vbus):
    """The same RS485 options as every other protocol: turnaround and echo suppression on the
    bus; an explicit kernel / soft-RTS mode is refused by a pty exactly as for FAP."""
    from fap_py.errors import PortError
    from fap_py.fap import RS485, RS485Mode
    from fap_py.vbus import VirtualBus

    quiet = RS485(mode=RS485Mode.NONE, turnaround_us=300)
    with Simulator(vbus.paths[1], [SimDevice(6)], rs485=quiet) as sim, \
            G485Master(vbus.paths[0], rs485=quiet, timeout=FAST) as master:
        assert master._io.port.mode is RS485Mode.NONE and master._io.port.rs485.turnaround_us == 300
        master.write(6, 8, [1, 2])
        assert master.read(6, 8, 2) == b"\x01\x02"
        assert sim.error is None
    for mode in (RS485Mode.KERNEL, RS485Mode.SOFT_RTS):
        with pytest.raises(PortError) as info:
            G485Master(vbus.paths[0], rs485=RS485(mode=mode))
        assert info.value.errno == 25  # ENOTTY: a pty has no RTS line nor RS-485 ioctls
    with VirtualBus(ports=2, echo=True, seed=3) as bus, Simulator(bus.paths[1], [SimDevice(5)]), \
            G485Master(bus.paths[0], rs485=RS485(echo_suppression=True), timeout=FAST) as master:
        assert master.read(5, 7) == b"\x05"
        assert master._io.port.stats.echo_bytes > 0
