"""Exceptions of the G485 module, all inside fap_py's one hierarchy.

``G485Error`` derives from :class:`fap_py.errors.FapError`; every other class
here also derives from the fap_py category it belongs to, so a caller can
catch ``FapTimeoutError`` (or plain ``TimeoutError``) for every kind of
"no answer", ``FrameError`` for every damaged frame, ``InvalidValueError``
(a ``ValueError``) for every bad argument.
"""
from __future__ import annotations

from ..errors import BusCollisionError, FapError, FapTimeoutError, FrameError, InvalidValueError


class G485Error(FapError):
    """Base of every G485 error."""


class G485ValueError(G485Error, InvalidValueError):
    """An argument is out of range: address, register, count, data, command."""


class BroadcastReadError(G485ValueError):
    """A read, error-word or handshake request was addressed to broadcast (0).

    The seed allows only User-Register-Write and Set on the broadcast address.
    """


class NoResponseError(G485Error, FapTimeoutError):
    """The device did not answer (completely) within the timeout."""


class G485FrameError(G485Error, FrameError):
    """A reply arrived but is damaged or is not the one expected."""


class CheckByteError(G485FrameError):
    """A reply's check byte does not match its content (bit error on the bus)."""

    def __init__(self, message: str, frame: bytes = b"") -> None:
        super().__init__(message)
        self.frame = frame


class UnexpectedReplyError(G485FrameError):
    """A reply with a valid check byte but the wrong PID or length."""


class EchoMismatchError(G485FrameError, BusCollisionError):
    """With ``echo=True``: what came back is not what the master sent."""


class CheckMismatchError(G485Error):
    """The check operation after a transaction says it failed."""


class HandshakeMismatchError(CheckMismatchError):
    """MDOC != SDOC (after a write or set) or MDIC != SDIC (after a read)."""

    def __init__(self, message: str, expected: int, got: int) -> None:
        super().__init__(message)
        self.expected = expected
        self.got = got


class WriteRefusedError(HandshakeMismatchError):
    """After a write the device's check byte is the one it held before: the device
    refused the packet (a read-only register, a value it rejects) or never got it."""


class RereadMismatchError(CheckMismatchError):
    """Re-reading the registers (or error word) gave different values."""


class DeviceErrorWordError(G485Error):
    """The device's error word is not zero (see ``ErrorBit`` for the bits)."""

    def __init__(self, address: int, word: int) -> None:
        from .codec import describe_error_word

        super().__init__(f"device {address}: error word 0x{word:04x} "
                         f"({describe_error_word(word)})")
        self.address = address
        self.word = word


#: errors after which a transaction is worth repeating
RETRYABLE_ERRORS = (NoResponseError, G485FrameError, CheckMismatchError)
