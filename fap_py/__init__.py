"""fap_py: RS-485 protocols (FAP, exec async, mikroC RS-485, Gicren G485).

FAP, exec async and mikroC run in libfap, the C core C programs link with;
this package wraps that core through a cffi extension (``fap_py._native``)
and adds pure-Python modules (G485) beside it.
"""
from __future__ import annotations

import importlib
import logging
from typing import TYPE_CHECKING, Any, List

from . import _protocols
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
    PortBusyError,
    PortError,
    PortGoneError,
    QueueFullError,
    RealTimeError,
    SlaveExistsError,
    UnknownSlaveError,
)

if TYPE_CHECKING:  # pragma: no cover
    from .fap import EventKind, Master, Message, Slave, SlaveEvent, Stats
    from .rs485 import RS485, RS485Mode

logging.getLogger(__name__).addHandler(logging.NullHandler())

# The classes over the C core are imported on first use (PEP 562), so that
# ``import fap_py`` and its pure-Python parts work before the extension is
# built (a source checkout) and stay cheap for the CLI.
_LAZY = {
    "Master": ".fap", "Slave": ".fap",
    "EventKind": ".fap", "Message": ".fap", "SlaveEvent": ".fap", "Stats": ".fap",
    "RS485": ".rs485", "RS485Mode": ".rs485",
}


# the protocols' binding modules come from the protocol table (fap_py._protocols)
_SUBMODULES = ("rs485", "vbus") + tuple(
    p.binding.rsplit(".", 1)[1] for p in _protocols.PROTOCOLS)


def __getattr__(name: str) -> Any:
    if name in _SUBMODULES:     # ``import fap_py; fap_py.fap.Node`` as before
        return importlib.import_module(f".{name}", __name__)
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> List[str]:
    return sorted(set(globals()) | set(_LAZY) | set(_SUBMODULES))


def native_version() -> str:
    """Version string of the libfap core compiled into the extension."""
    from ._native import ffi, lib

    return ffi.string(lib.fap_version_string()).decode()


__version__ = "0.1.0"

__all__ = [
    # the one exception hierarchy (fap_py.errors)
    "FapError", "InvalidValueError", "InvalidTypeError", "NotMasterError", "SlaveExistsError",
    "UnknownSlaveError", "NotInitialisedError", "QueueFullError", "ClosedError", "FapTimeoutError",
    "FrameError", "BusCollisionError", "PortError", "PortBusyError", "PortGoneError", "RealTimeError",
    # the classes over the C core, imported on first use (_LAZY)
    "Master", "Slave", "EventKind", "Message", "SlaveEvent", "Stats", "RS485", "RS485Mode",
    # this module's own
    "native_version", "__version__",
]
