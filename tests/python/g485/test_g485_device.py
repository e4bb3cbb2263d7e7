"""The simulated device alone (sans-I/O): frames in, replies out."""
from __future__ import annotations

import json

import pytest

from fap_py.g485 import codec
from fap_py.g485.codec import ErrorBit, Parser, SetCommand, decode_frame
from fap_py.g485.device import RegisterSpec, SimDevice
from fap_py.g485.errors import G485ValueError


def send(dev: SimDevice, *frames: bytes) -> list:
    """Parse ``frames`` and hand every event to ``dev``; return its replies, decoded."""
    replies = []
    parser = Parser()
    for frame in frames:
        for ev in parser.feed(frame):
            out = dev.handle(ev)
            if out is not None:
                replies.append(decode_frame(out))
    return replies


def read(dev, register, count=1):
    (reply,) = send(dev, codec.encode_read_request(dev.address, register, count))
    return reply.data


def test_common_registers_and_access_rules():
    dev = SimDevice(5, identity=(11, 2, 3, 4, 5))
    assert read(dev, 1, 7) == bytes((11, 2, 3, 4, 5, 0, 5))
    send(dev, codec.encode_write(5, 2, 9))  # read-only
    assert dev.error_word == ErrorBit.READ_ONLY and read(dev, 2) == b"\x02"
    send(dev, codec.encode_set(5, SetCommand.CLEAR_ERROR_WORD))
    send(dev, codec.encode_write(5, 6, 0x42))  # write-only command byte
    assert dev.commands == [0x42] and read(dev, 6) == b"\x00" and dev.error_word == 0


def test_private_register_rules():
    dev = SimDevice(1, private={8: RegisterSpec("R", 0x20), 9: ("W", 0)})
    assert read(dev, 8, 2) == b"\x20\x00"
    send(dev, codec.encode_write(1, 8, [1, 2]))  # covers a read-only register: whole write refused
    assert dev.error_word & ErrorBit.READ_ONLY and read(dev, 8, 2) == b"\x20\x00"
    dev.set_register(8, 0x33)  # a "sensor" changes it from inside
    assert read(dev, 8) == b"\x33"
    with pytest.raises(G485ValueError):
        SimDevice(1, private={7: ("RW", 0)})


def test_register_range_error_and_no_reply():
    dev = SimDevice(1)
    bad = codec._frame(3, 99, b"\x05")  # registers 99..103
    assert send(dev, bad) == [] and dev.error_word & ErrorBit.REGISTER_RANGE


def test_id_change_real_time_and_refused_value():
    dev = SimDevice(1)
    send(dev, codec.encode_write(1, 7, 9))
    assert dev.address == 9 and send(dev, codec.encode_handshake_request(1)) == []
    send(dev, codec._frame(9 << 1, 7, b"\x7f"))  # ID 127 is the master's
    assert dev.address == 9 and dev.error_word & ErrorBit.BAD_VALUE


def test_non_real_time_writes_wait_for_0x77():
    seen = []
    dev = SimDevice(1, on_apply=lambda d, first, last: seen.append((first, last)))
    send(dev, codec.encode_set(1, SetCommand.NON_REAL_TIME_WRITE), codec.encode_write(1, 10, [1, 2, 3]),
         codec.encode_write(1, 20, 4))
    assert read(dev, 10, 3) == b"\x01\x02\x03"  # the register changed...
    assert dev.applied[10:13] == b"\x00\x00\x00" and seen == []  # ...but is not performed
    assert dev.pending_writes == {10: 1, 11: 2, 12: 3, 20: 4}
    send(dev, codec.encode_set(0, SetCommand.APPLY_WRITES))
    assert dev.applied[10:13] == b"\x01\x02\x03" and seen == [(10, 12), (20, 20)]
    send(dev, codec.encode_set(1, SetCommand.REAL_TIME_WRITE), codec.encode_write(1, 30, 7))
    assert dev.applied[30] == 7 and seen[-1] == (30, 30)


def test_eeprom_save_reset_restore_and_factory_reset(tmp_path):
    path = tmp_path / "dev.json"
    dev = SimDevice(1, eeprom_path=path)
    send(dev, codec.encode_write(1, 8, [11, 12]), codec.encode_write(1, 7, 3))
    send(dev, codec.encode_set(3, SetCommand.SAVE_EEPROM))
    doc = json.loads(path.read_text())
    assert doc["registers"]["8"] == 11 and doc["registers"]["7"] == 3 and "6" not in doc["registers"]
    send(dev, codec.encode_write(3, 8, 99), codec.encode_set(3, SetCommand.RESET))
    assert read(dev, 8) == b"\x0b"  # unsaved change lost by the reset
    again = SimDevice(1, eeprom_path=path)  # "power-on" from the file
    assert again.address == 3 and read(again, 8, 2) == b"\x0b\x0c"
    send(again, codec.encode_set(3, SetCommand.LOCK_BAUD_RATE))
    assert json.loads(path.read_text())["baud_locked"] is True
    send(again, codec.encode_set(3, SetCommand.FACTORY_RESET))
    assert again.address == 1 and read(again, 8, 2) == b"\x00\x00" and not again.baud_locked
    assert json.loads(path.read_text())["registers"]["7"] == 1


def test_unusable_eeprom_file_sets_error_bit(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text("{not json")
    dev = SimDevice(4, eeprom_path=path)
    assert dev.address == 4 and dev.error_word == ErrorBit.EEPROM


def test_reset_restores_modes_and_clears_error_word():
    dev = SimDevice(1)
    send(dev, codec.encode_set(1, SetCommand.NON_REAL_TIME_WRITE), codec.encode_set(1, SetCommand.BULK_MODE),
         codec.encode_write(1, 1, 0))
    assert dev.error_word and not dev.real_time and dev.bulk_mode
    send(dev, codec.encode_set(1, SetCommand.RESET))
    assert dev.error_word == 0 and dev.real_time and not dev.bulk_mode


def test_handshake_state_after_each_packet_type():
    dev = SimDevice(1)
    write = codec.encode_write(1, 8, 5)
    send(dev, write)
    (hs,) = send(dev, codec.encode_handshake_request(1))
    assert hs.handshake_value == write[-1]  # SDOC of the write
    (hs2,) = send(dev, codec.encode_handshake_request(1))
    assert hs2.handshake_value == write[-1]  # a handshake does not change it
    (resp,) = send(dev, codec.encode_read_request(1, 8, 1))
    assert send(dev, codec.encode_handshake_request(1))[0].handshake_value == resp.check  # SDIC
    (err,) = send(dev, codec.encode_error_word_request(1))
    assert send(dev, codec.encode_handshake_request(1))[0].handshake_value == err.check
    setf = codec.encode_set(1, SetCommand.CONTROL_MODE)
    send(dev, setf)
    assert send(dev, codec.encode_handshake_request(1))[0].handshake_value == setf[-1]
    bcast = codec.encode_set(0, SetCommand.CLEAR_ERROR_WORD)
    send(dev, bcast)
    assert send(dev, codec.encode_handshake_request(1))[0].handshake_value == bcast[-1]


def test_bad_check_sets_bit_keeps_check_byte_and_is_not_executed():
    dev = SimDevice(1)
    send(dev, codec.encode_write(1, 8, 1))
    before = dev.check_byte
    bad = bytearray(codec.encode_write(1, 8, 2))
    bad[-1] ^= 0x01
    assert send(dev, bytes(bad)) == []
    assert dev.error_word & ErrorBit.BAD_CHECK and dev.check_byte == before and dev.registers[8] == 1


def test_weakness_a_lost_set_passes_the_handshake():
    """The seed's example: the check byte already equals the Set's, the Set is lost."""
    dev = SimDevice(1)
    save = codec.encode_set(1, SetCommand.SAVE_EEPROM)
    send(dev, save)  # first Set received: check byte = its MDOC
    send(dev, codec.encode_write(1, 8, 77))
    clear = codec.encode_set(1, SetCommand.CLEAR_ERROR_WORD)
    dev.check_byte = clear[-1]  # coincidence: the device already holds the next Set's check byte
    dev.error_word = ErrorBit.READ_ONLY
    # the Set 0x7A never arrives; the handshake still matches its MDOC
    (hs,) = send(dev, codec.encode_handshake_request(1))
    assert hs.handshake_value == clear[-1] and dev.error_word == ErrorBit.READ_ONLY


def test_broadcast_read_sets_bit_and_gets_no_reply():
    dev = SimDevice(1)
    assert send(dev, codec._frame(1, 8, b"\x01")) == []
    assert dev.error_word == ErrorBit.BROADCAST_READ


def test_replies_of_other_devices_are_ignored():
    dev = SimDevice(1)
    assert send(dev, codec.encode_read_response(1, b"\x01"), codec.encode_handshake_response(3)) == []
    assert dev.packets_handled == 0


def test_bulk_mode_discards_deterministically():
    def run(seed):
        dev = SimDevice(1, seed=seed, bulk_discard_rate=0.5)
        send(dev, codec.encode_set(1, SetCommand.BULK_MODE))
        answered = [bool(send(dev, codec.encode_read_request(1, 1, 1))) for _ in range(40)]
        hs = [bool(send(dev, codec.encode_handshake_request(1))) for _ in range(10)]
        return answered, hs, dev

    a, hs, dev = run(3)
    assert a == run(3)[0] and not all(a) and any(a)
    assert all(hs)  # handshakes and Sets are never discarded
    assert dev.discarded_in_bulk == a.count(False) and dev.error_word & ErrorBit.DISCARDED
    send(dev, codec.encode_set(1, SetCommand.CONTROL_MODE))
    assert all(send(dev, codec.encode_read_request(1, 1, 1)) for _ in range(20))


def test_wake_up_loss_eats_the_first_burst():
    dev = SimDevice(1, wake_up_loss=True)
    assert send(dev, codec.encode_handshake_request(1)) == []  # lost to baud detection
    assert send(dev, codec.encode_handshake_request(1)) != []
    dev2 = SimDevice(1, wake_up_loss=True)
    assert send(dev2, codec.WAKE_UP_PREAMBLE + codec.encode_handshake_request(1)) != []
    send(dev2, codec.encode_set(1, SetCommand.RESET))
    assert dev2.asleep
