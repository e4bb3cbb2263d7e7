"""Exec async protocol (DLE STX ... DLE ETX + CRC-16) over libfap.

Everything here runs in the C core (``include/exec_async.h`` and
``include/exec_async_engine.h``) through the cffi extension:

* :func:`encode` / :class:`Decoder`: ``execAsyncBufferOut`` and
  ``execAsyncByteIn`` (one frame per call / a byte stream).
* :class:`StructLayout`: ``execPackDataEx`` / ``execUnPackDataEx`` from a
  Python description of a C structure (native layout <-> packed big-endian).
* :class:`Master` and :class:`Slave`: the master/slave engine on a libfap
  port (a serial device or a :class:`fap_py.vbus.VirtualBus` port), with
  per-node sequence numbers, retries and the resend-without-processing
  rule. Time values are in seconds.

Example::

    line = RS485(mode=RS485Mode.NONE)
    with VirtualBus(ports=2) as bus, \\
         Slave(bus.paths[1], node=1, handler=lambda req: req.data[::-1], rs485=line) as slave, \\
         Master(bus.paths[0], timeout=0.05, rs485=line) as master:
        slave.start()
        assert master.transact(1, b"abc") == b"cba"
"""
from ..rs485 import RS485, RS485Mode
from .codec import (
    BROADCAST,
    DEFAULT_BAUD,
    DLE,  # noqa: F401  (public, not in __all__: as before)
    ETX,  # noqa: F401
    MAX_DATA,
    MAX_FRAME,
    NODE_MAX,
    NODE_MIN,
    STX,  # noqa: F401
    Decoder,
    Frame,
    Status,
    encode,
)
from .daemon import DaemonMaster
from .errors import CorruptReplyError, ExecAsyncError, ExecTypeError, ExecValueError, NoReplyError
from .layout import StructLayout
from .master import Master
from .node import MasterStats, SlaveStats
from .slave import Request, ServeResult, Slave

__all__ = [
    "RS485", "RS485Mode", "BROADCAST", "NODE_MIN", "NODE_MAX", "DEFAULT_BAUD", "MAX_DATA", "MAX_FRAME", "CorruptReplyError", "DaemonMaster", "Decoder", "ExecAsyncError",
    "ExecTypeError", "ExecValueError", "Frame", "Master", "MasterStats", "NoReplyError", "Request",
    "ServeResult", "Slave", "SlaveStats", "Status", "StructLayout", "encode",
]

