"""Exceptions for the vendor's classic FAP API (``include/fap.h``) return codes.

For Python code that calls the classic API through ``fap_py._native``. The
codes are the C core's (``GOOD``, ``BAD``, ``E_PARAM`` ...), taken through
cffi.
"""
from __future__ import annotations

from .._native import lib
from .._validate import check_int
from ..errors import FapError, InvalidValueError, NotInitialisedError, QueueFullError

__all__ = ["classic_check"]

_CLASSIC_TEXT = {lib.BAD: "BAD (port could not be opened, or baud rate not 9600..115200)",
                 lib.E_PARAM: "E_PARAM (wrong mode, or a slave-list call on a slave)",
                 lib.E_VALUE: "E_VALUE (ID or size out of range, slave listed twice or not listed)",
                 lib.E_INIT: "E_INIT (fapInit/fapConfig not done, or the handle was closed)",
                 lib.E_RES: "E_RES (queue full or empty)"}


def classic_check(code: int, what: str) -> None:
    """Raise the exception for a vendor-API (``fap.h``) return code; GOOD passes.

    ``classic_check(lib.fapTx(data, len(data), 3), "fapTx")``. ``E_RES`` is
    :class:`QueueFullError` (from ``fapTx``; ``fapRx`` returns it for "nothing
    received", which callers test for before calling this).
    """
    code = check_int(code, "code", -(1 << 63), (1 << 64) - 1)
    if code == lib.GOOD:
        return
    msg = f"{what}: {_CLASSIC_TEXT.get(code, f'unknown code {code}')}"
    if code in (lib.E_PARAM, lib.E_VALUE):
        raise InvalidValueError(msg)
    if code == lib.E_INIT:
        raise NotInitialisedError(msg)
    if code == lib.E_RES:
        raise QueueFullError(msg)
    raise FapError(msg)
