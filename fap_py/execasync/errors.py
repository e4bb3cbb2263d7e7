"""exec async's exceptions and the C result codes they come from."""
from __future__ import annotations

import errno
from typing import Any, Dict, Optional

from .._native import ffi, lib
from ..errors import (
    ClosedError,
    FapError,
    FapTimeoutError,
    FrameError,
    InvalidTypeError,
    InvalidValueError,
    PortError,
    error_from_code,
)

# ---- errors -----------------------------------------------------------------

class ExecAsyncError(FapError):
    """Base of the exec async errors."""


class ExecValueError(ExecAsyncError, InvalidValueError):
    """A node number, payload or structure description is out of range."""


class ExecTypeError(ExecValueError, InvalidTypeError):
    """An argument has the wrong type (also an InvalidTypeError / TypeError)."""


class NoReplyError(ExecAsyncError, FapTimeoutError):
    """The node did not answer, after every retry."""


class CorruptReplyError(ExecAsyncError, FrameError):
    """Every attempt failed and the last one got a corrupted frame (CRC, framing)."""


def _raise_for(code: int, what: str, path: Optional[str] = None) -> None:
    if code >= 0:
        return
    if code == -errno.ETIMEDOUT:
        if what in ("open", "reopen"):   # no connection within connect_ms: a port error
            raise PortError(errno.ETIMEDOUT, f"{what}: connection timed out", path)
        raise NoReplyError(f"{what}: no reply")
    if code == -errno.EBADMSG:
        raise CorruptReplyError(f"{what}: corrupted reply")
    if code in (-errno.EINVAL, -errno.EMSGSIZE):
        raise ExecValueError(f"{what}: {ffi.string(lib.fap_port_strerror(code)).decode()}")
    if code == -errno.ECANCELED:
        raise ClosedError(f"{what}: stopped")
    raise error_from_code(code, what, path)


_ERR: Dict[str, Any] = {"error": ExecValueError, "type_error": ExecTypeError}
