"""Gicren G485 (G485_V11) in pure Python: codec, master and device simulator.

>>> from fap_py.g485 import G485Master, SetCommand
>>> with G485Master("/dev/ttyUSB0", 115200) as bus:          # doctest: +SKIP
...     data = bus.read(1, 1, 7)                              # registers 1..7 of device 1
...     bus.write(1, 8, [0x32])
...     bus.set(1, SetCommand.SAVE_EEPROM)

See docs/g485.md for every decision the vendor document leaves open.
"""
from ..rs485 import DEFAULT_BAUD
from .codec import (
                    BROADCAST,
                    MASTER_ADDRESS,
                    WAKE_UP_PREAMBLE,
                    Discarded,
                    ErrorBit,
                    Packet,
                    PacketKind,
                    ParseIssue,
                    Parser,
                    SetCommand,
                    decode_frame,
                    describe_error_word,
                    encode_error_word_request,
                    encode_error_word_response,
                    encode_handshake_request,
                    encode_handshake_response,
                    encode_read_request,
                    encode_read_response,
                    encode_set,
                    encode_write,
)
from .codec import MAX_SLAVE_ADDRESS as NODE_MAX
from .codec import MIN_SLAVE_ADDRESS as NODE_MIN
from .daemon import DaemonG485Master
from .device import RegisterSpec, SimDevice
from .errors import (
                    BroadcastReadError,
                    CheckByteError,
                    CheckMismatchError,
                    DeviceErrorWordError,
                    EchoMismatchError,
                    G485Error,
                    G485FrameError,
                    G485ValueError,
                    HandshakeMismatchError,
                    NoResponseError,
                    RereadMismatchError,
                    UnexpectedReplyError,
                    WriteRefusedError,
)
from .master import Check, G485Master, MasterStats
from .simulator import Simulator

__all__ = [
    "BROADCAST", "NODE_MIN", "NODE_MAX", "DEFAULT_BAUD", "MASTER_ADDRESS", "WAKE_UP_PREAMBLE", "Discarded", "ErrorBit", "Packet", "PacketKind",
    "ParseIssue", "Parser", "SetCommand", "decode_frame", "describe_error_word", "encode_error_word_request",
    "encode_error_word_response", "encode_handshake_request", "encode_handshake_response",
    "encode_read_request", "encode_read_response", "encode_set", "encode_write",
    "RegisterSpec", "SimDevice",
    "BroadcastReadError", "CheckByteError", "CheckMismatchError", "DeviceErrorWordError", "G485Error",
    "EchoMismatchError", "G485FrameError", "G485ValueError", "HandshakeMismatchError", "NoResponseError",
    "RereadMismatchError",
    "UnexpectedReplyError", "WriteRefusedError",
    "Check", "DaemonG485Master", "G485Master", "MasterStats", "Simulator",
]
