"""mikroC frame errors: one class per C ``MIKROC_RS485_E*`` code."""
from __future__ import annotations

from typing import Optional

from .._native import ffi, lib
from ..errors import FrameError

__all__ = ["AbortedFrameError", "ChecksumError", "FormatError", "LongFrameError", "MikrocFrameError",
           "OverrunError", "ShortFrameError"]


class MikrocFrameError(FrameError):
    """A mikroC frame failed its checks. ``code`` is the C MIKROC_RS485_E*
    value; ``address`` the address it carried, when that arrived."""

    def __init__(self, code: int, address: Optional[int] = None) -> None:
        text = ffi.string(lib.mikrocRS485_strerror(code)).decode()
        if address is not None:
            text = f"{text} (address {address})"
        super().__init__(text)
        self.code = code
        self.address = address


class ChecksumError(MikrocFrameError):
    """The CRC byte does not match the frame."""


class FormatError(MikrocFrameError):
    """DATALEN bit 5 set, or escape flags that do not fit the bytes."""


class ShortFrameError(MikrocFrameError):
    """The stop byte came before the frame was complete."""


class LongFrameError(MikrocFrameError):
    """No stop byte where DATALEN put it."""


class AbortedFrameError(MikrocFrameError):
    """A new start byte cut the frame off."""


class OverrunError(MikrocFrameError):
    """A frame arrived while the previous one was still unread."""


_ERRORS = {
    lib.MIKROC_RS485_ECRC: ChecksumError,
    lib.MIKROC_RS485_EFORMAT: FormatError,
    lib.MIKROC_RS485_ESHORT: ShortFrameError,
    lib.MIKROC_RS485_ELONG: LongFrameError,
    lib.MIKROC_RS485_EABORT: AbortedFrameError,
    lib.MIKROC_RS485_EOVERRUN: OverrunError,
}


def _frame_error(code: int, address: Optional[int] = None) -> MikrocFrameError:
    return _ERRORS.get(code, MikrocFrameError)(code, address)
