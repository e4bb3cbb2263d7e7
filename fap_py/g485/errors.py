"""Exceptions of the G485 module, all inside fap_py's one hierarchy.

``G485Error`` derives from :class:`fap_py.errors.FapError`; every other class
here also derives from the fap_py category it belongs to, so a caller can
catch ``FapTimeoutError`` (or plain ``TimeoutError``) for every kind of
"no answer", ``FrameError`` for every damaged frame, ``InvalidValueError``
(a ``ValueError``) for every bad argument.
"""
from __future__ import annotations

import enum

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


class ErrorBit(enum.IntFlag):
    """Bits of the error word (the device's own faults) as this library defines them (the seed does not).

    ERRL (bits 0..7) holds communication errors set by the simulator; ERRH
    (bits 8..15) is left to the device's own (private) faults.
    """

    BAD_CHECK = 0x0001        # a packet for this device had a wrong check byte
    MALFORMED = 0x0002        # unknown PID or a length that does not fit the PID
    REGISTER_RANGE = 0x0004   # register / count outside 1..100
    READ_ONLY = 0x0008        # write to a read-only register (1..5 or private R)
    BAD_VALUE = 0x0010        # value refused (ID outside 1..126, ...)
    EEPROM = 0x0020           # EEPROM (file) save or restore failed
    BROADCAST_READ = 0x0040   # a read / error word / handshake sent to broadcast
    DISCARDED = 0x0080        # a packet was discarded in bulk transmission mode


def describe_error_word(word: int) -> str:
    """Names of the bits set in ``word`` (a 16-bit error word; ``"none"`` for 0)."""
    if isinstance(word, bool) or not isinstance(word, int) or not 0 <= word <= 0xFFFF:
        raise G485ValueError(f"an error word is an int 0..0xffff, not {word!r}")
    if not word:
        return "none"
    names = [b.name for b in ErrorBit if word & b and b.name]
    rest = word & ~sum(int(b) for b in ErrorBit)
    if rest:
        names.append(f"device-specific 0x{rest:04x}")
    return ", ".join(str(n) for n in names)


class DeviceErrorWordError(G485Error):
    """The device's error word is not zero (see ``ErrorBit`` for the bits)."""

    def __init__(self, address: int, word: int) -> None:
        super().__init__(f"device {address}: error word 0x{word:04x} "
                         f"({describe_error_word(word)})")
        self.address = address
        self.word = word


#: errors after which a transaction is worth repeating
RETRYABLE_ERRORS = (NoResponseError, G485FrameError, CheckMismatchError)
