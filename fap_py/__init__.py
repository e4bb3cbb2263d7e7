"""fap_py: RS-485 protocols (FAP, exec async, mikroC RS-485, Gicren G485).

FAP, exec async and mikroC run in libfap, the C core C programs link with;
this package wraps that core through a cffi extension (``fap_py._native``)
and adds pure-Python modules (G485) beside it.
"""
from __future__ import annotations

import logging

from .errors import (
    BusCollisionError,
    ClosedError,
    FapError,
    FapTimeoutError,
    FrameError,
    InvalidTypeError,
    InvalidValueError,
    NotInitialisedError,
    NotMasterError,
    PortError,
    QueueFullError,
    SlaveExistsError,
    UnknownSlaveError,
)
from .fap import Master, Slave
from .fap_types import EventKind, Message, SlaveEvent, Stats
from .rs485 import RS485, RS485Mode

logging.getLogger(__name__).addHandler(logging.NullHandler())


def native_version() -> str:
    """Version string of the libfap core compiled into the extension."""
    from ._native import ffi, lib

    return ffi.string(lib.fap_version_string()).decode()


__version__ = "0.1.0"

__all__ = [
    "BusCollisionError",
    "ClosedError",
    "FapError",
    "FapTimeoutError",
    "FrameError",
    "InvalidValueError",
    "NotInitialisedError",
    "PortError",
    "QueueFullError",
    "native_version",
    "EventKind",
    "InvalidTypeError",
    "Master",
    "Message",
    "NotMasterError",
    "RS485",
    "RS485Mode",
    "Slave",
    "SlaveEvent",
    "SlaveExistsError",
    "Stats",
    "UnknownSlaveError",
    "__version__",
]
