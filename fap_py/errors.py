"""The one exception hierarchy of fap_py.

Every error the package raises derives from :class:`FapError`. Where a
built-in category fits, the class also derives from it (``InvalidValueError``
is a ``ValueError``, ``PortError`` an ``OSError``, ``FapTimeoutError`` a
``TimeoutError``) so generic handlers keep working.

Protocol modules add subclasses (``fap_py.g485.NoResponseError`` ...), never
parallel hierarchies.
"""
from __future__ import annotations

import errno as _errno
import functools
import os
import re
from typing import Dict


class FapError(Exception):
    """Base of every fap_py error."""


class InvalidValueError(FapError, ValueError):
    """An argument is out of range or of the wrong kind (C: E_VALUE/E_PARAM)."""

    def __init__(self, *args: object) -> None:
        if len(args) == 1 and isinstance(args[0], str):
            args = (_undouble(args[0]),)
        super().__init__(*args)


def _undouble(text: str) -> str:
    """``open: invalid argument (invalid argument (ID ...))`` -> ``open:
    invalid argument (ID ...)``: a C ``*_strerror()`` text appended after
    the same words (issue 25: the message said it twice)."""
    m = re.search(r"(\w[\w ]*) \(\1 \((.*)\)\)$", text)
    return f"{text[:m.start()]}{m.group(1)} ({m.group(2)})" if m else text


class InvalidTypeError(InvalidValueError, TypeError):
    """An argument has the wrong type (also a ``TypeError``)."""


class NotMasterError(InvalidValueError):
    """A slave-list operation was asked of a slave node (C: -EPERM)."""


class SlaveExistsError(InvalidValueError):
    """add_slave: the slave is already listed (C: -EEXIST)."""


class UnknownSlaveError(InvalidValueError):
    """The slave is not listed on this master (C: -ENOENT)."""


class NotInitialisedError(FapError):
    """The bus or engine is not initialised / configured yet (C: E_INIT)."""


class QueueFullError(FapError):
    """A transmit queue is full (C: E_RES on transmit)."""


class ClosedError(FapError):
    """The object was closed."""


class FapTimeoutError(FapError, TimeoutError):
    """No answer (or no data) within the allowed time."""


class FrameError(FapError):
    """A frame on the wire failed its checks (CRC, length, format)."""


class BusCollisionError(FapError):
    """What was read back from the bus differs from what was sent."""


class PortError(FapError, OSError):
    """The serial port failed; ``errno`` holds the OS error number."""

    def __init__(self, err: int, message: str | None = None, path: str | None = None) -> None:
        text = message or os.strerror(err)
        if path:
            text = f"{path}: {text}"
        super().__init__(err, text)
        self.path = path


class PortBusyError(PortError):
    """Another process (or another Port) holds the device: the exclusive lock (EBUSY)."""


class PortGoneError(PortError):
    """The device vanished (EIO, ENXIO, ENODEV, EPIPE, EBADF; ``fap_port_error_is_gone``):
    unplugged, or the far end of a pty or a connection closed."""


class FileError(PortError):
    """A file named by the user cannot be used: missing, unreadable, not a
    regular file (a directory, ``/dev/zero``, a FIFO) or larger than its bound
    (``fap_py._files``). Also a :class:`PortError` (and an ``OSError``): the
    command line's "bad file" exit status 3."""

    #: what is wrong with the file, without its name (set by ``fap_py._files``)
    why: str = ""


class RealTimeError(PortError):
    """The real-time option (docs/realtime.md) was refused at open: no
    privilege for SCHED_FIFO/RR (``errno`` EPERM), a CPU the process may not
    use (EINVAL) or mlockall refused (ENOMEM)."""


@functools.lru_cache(maxsize=None)
def _port_codes() -> Dict[str, int]:
    """libfap's own negative codes (include/fap_port.h), from the compiled core.

    Looked up on first use, so that importing this module (and the pure-Python
    parts of fap_py) does not need the extension."""
    from ._native import lib

    names = ("FAP_PORT_ECOLLISION", "FAP_PORT_ECLOSED", "FAP_PORT_EURL", "FAP_PORT_ENET485",
             "FAP_PORT_ERESOLVE", "FAP_PORT_EREFUSED",
             "FAP_PORT_ERTPRIV", "FAP_PORT_ERTCPU", "FAP_PORT_EMLOCK")
    return {name: int(getattr(lib, name)) for name in names}


def _device_gone(code: int) -> bool:
    """Whether the negative code says the device is gone: the C core's one
    list (fap_port_error_is_gone), not a copy of it."""
    from ._native import lib

    return bool(lib.fap_port_error_is_gone(code))


def _net_error(code: int, prefix: str, path: str | None) -> FapError | None:
    """The exception for a network transport's code (tcp://, rfc2217://), or None.

    A bad URL or an RS-485 mode a URL cannot have is a usage error; a name
    that does not resolve, a server that refuses a setting or a connect that
    times out is a port error (docs/port.md, "Network transports")."""
    from ._native import ffi, lib

    codes = _port_codes()
    text = f"{prefix}{ffi.string(lib.fap_port_strerror(code)).decode()}"
    if code in (codes["FAP_PORT_EURL"], codes["FAP_PORT_ENET485"]):
        return InvalidValueError(f"{path}: {text}" if path else text)
    if code == codes["FAP_PORT_ERESOLVE"]:
        return PortError(_errno.EHOSTUNREACH, text, path)
    if code == codes["FAP_PORT_EREFUSED"]:
        return PortError(_errno.EPROTO, text, path)
    # what the path is: the C core's one reading (fap_port_kind), not a guess here
    try:
        kind = lib.fap_port_kind(os.fsencode(path)) if path and "\0" not in path else None
    except (TypeError, UnicodeError):
        kind = None
    network = kind in (lib.FAP_PORT_KIND_TCP, lib.FAP_PORT_KIND_RFC2217)
    if code == -_errno.ETIMEDOUT and network and "open" in prefix:
        return PortError(_errno.ETIMEDOUT, f"{prefix}connection timed out", path)
    if code == -_errno.EPROTO and path and kind == lib.FAP_PORT_KIND_RFC2217:
        raw = "tcp://" + path[len("rfc2217://"):].split("?", 1)[0]
        return PortError(_errno.EPROTO, f"{prefix}the server sent no Telnet negotiation within "
                         f"option_ms: not an RFC 2217 server (a raw TCP port? use {raw})", path)
    if code == -_errno.EIO and network:
        text = f"{prefix}connection closed by the server"
        return PortError(_errno.EIO, text, path) if "open" in prefix \
            else PortGoneError(_errno.EIO, text, path)
    return None


def __getattr__(name: str) -> int:
    if name in ("FAP_PORT_ECOLLISION", "FAP_PORT_ECLOSED"):
        return _port_codes()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _held_by(path: str | None) -> str:
    """``held by pid 123 (fap serve ...)`` when a lock file or /proc/locks names the
    holder of a device path, else the general words (a URL names no file: nothing found)."""
    if path and os.path.exists(path):
        from ._holder import describe, holder  # nothing above errors: _holder is os-only

        pid = holder(path)
        if pid is not None and pid != os.getpid():
            return f"held by {describe(pid)}"
    return "held by another process or port"


def error_from_code(code: int, what: str = "", path: str | None = None) -> FapError:
    """Map a negative libfap port-layer return code to an exception instance."""
    if type(code) is not int:
        raise InvalidTypeError(f"code must be an int (a negative libfap code), not {code!r}")
    prefix = f"{what}: " if what else ""
    codes = _port_codes()
    if code == codes["FAP_PORT_ECOLLISION"]:
        return BusCollisionError(f"{prefix}bus collision (echo differs from what was sent)")
    if code == codes["FAP_PORT_ECLOSED"]:
        return ClosedError(f"{prefix}port closed")
    net = _net_error(code, prefix, path)
    if net is not None:
        return net
    rt = {codes["FAP_PORT_ERTPRIV"]: _errno.EPERM, codes["FAP_PORT_ERTCPU"]: _errno.EINVAL,
          codes["FAP_PORT_EMLOCK"]: _errno.ENOMEM}.get(code)
    if rt is not None:   # the real-time option refused (docs/realtime.md)
        from ._native import ffi, lib
        return RealTimeError(rt, f"{prefix}{ffi.string(lib.fap_port_strerror(code)).decode()}",
                             path)
    err = -code
    if err == _errno.ETIMEDOUT:
        return FapTimeoutError(f"{prefix}{os.strerror(err)}")
    if err in (_errno.EINVAL, _errno.ERANGE):
        return InvalidValueError(f"{prefix}{os.strerror(err)}")
    if err == _errno.EBUSY:
        return PortBusyError(err, f"{prefix}port busy ({_held_by(path)})", path)
    if _device_gone(code):
        return PortGoneError(err, f"{prefix}{os.strerror(err)} (device gone)", path)
    return PortError(err, f"{prefix}{os.strerror(err)}", path)
