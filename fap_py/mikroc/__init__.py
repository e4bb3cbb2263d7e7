"""mikroC RS-485 library (master/slave, 0..3 data bytes per frame).

The frame codec and the master/slave logic run in libfap's C core
(``include/mikroc_rs485.h``); this module calls them through cffi.

Frame on the wire::

    0x96 | ADDRESS | DATALEN | DATA1..3 | CRC | 0xA9

Codec (no I/O)::

    frame = encode(0x12, b"\\x01\\x02")              # master -> slave 0x12
    for event in Decoder().feed(frame):              # Message or a FrameError
        ...

Nodes on a serial port (or a :class:`fap_py.vbus.VirtualBus` port)::

    with Master("/dev/ttyUSB0", 19200) as m, ...:
        m.send(0x12, b"\\x01")
        reply = m.receive(timeout=0.5)               # Message(address=0x12, ...)

    with Slave("/dev/ttyUSB1", 19200, address=0x12) as s:
        msg = s.receive(timeout=None)                # blocks until a frame for us
        s.send(b"\\x02")

Rules (docs/mikroc.md): address 50 is broadcast (every slave but those at
150 and 169 takes it); slaves ignore frames for other addresses and frames
sent by other slaves; a damaged frame whose address (and direction) say it
is for this node raises a :class:`MikrocFrameError` subclass from
``receive``; more than 3 data bytes is refused, never truncated.
"""
from .codec import (
    BROADCAST,
    DEFAULT_BAUD,
    MAX_DATA,
    NODE_MAX,
    NODE_MIN,
    START_BYTE,
    STOP_BYTE,
    Decoder,
    Message,
    decode,
    encode,
)
from .daemon import DaemonMaster
from .errors import (
    AbortedFrameError,
    ChecksumError,
    FormatError,
    LongFrameError,
    MikrocFrameError,
    OverrunError,
    ShortFrameError,
)
from .master import Master
from .node import NodeStats
from .slave import Slave

__all__ = [
    "NODE_MIN",
    "NODE_MAX",
    "DEFAULT_BAUD",
    "BROADCAST",
    "MAX_DATA",
    "START_BYTE",
    "STOP_BYTE",
    "AbortedFrameError",
    "ChecksumError",
    "DaemonMaster",
    "Decoder",
    "FormatError",
    "LongFrameError",
    "Master",
    "Message",
    "MikrocFrameError",
    "NodeStats",
    "OverrunError",
    "ShortFrameError",
    "Slave",
    "decode",
    "encode",
]
