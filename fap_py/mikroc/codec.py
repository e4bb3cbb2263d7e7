"""The mikroC frame codec (the C one, no I/O) and the protocol's constants.

Frame on the wire::

    0x96 | ADDRESS | DATALEN | DATA1..3 | CRC | 0xA9
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Union

from .._native import ffi, lib
from .._validate import check_bool, check_bytes, check_int
from ..errors import FrameError, error_from_code
from .errors import MikrocFrameError, _frame_error

__all__ = ["BROADCAST", "DEFAULT_BAUD", "MAX_DATA", "NODE_MAX", "NODE_MIN", "START_BYTE", "STOP_BYTE",
           "Decoder", "Message", "decode", "encode"]

START_BYTE: int = lib.MIKROC_RS485_START_BYTE
STOP_BYTE: int = lib.MIKROC_RS485_STOP_BYTE
BROADCAST: int = lib.MIKROC_RS485_BROADCAST
MAX_DATA: int = lib.MIKROC_RS485_MAX_DATA
# Facts the tools read through fap_py._protocols (never re-typed in a tool).
NODE_MIN: int = lib.MIKROC_RS485_ADDR_MIN       # any address byte a master may send to
NODE_MAX: int = lib.MIKROC_RS485_ADDR_MAX
DEFAULT_BAUD: int = 19200                       # the rate of the vendor's mikroC examples


@dataclass(frozen=True)
class Message:
    """A valid frame: the address it carried, its data, and its direction.

    For a master the address is the replying slave's; for a slave it is the
    address the master sent to (its own, or :data:`BROADCAST`)."""

    address: int
    data: bytes
    from_master: bool


def _check_address(address: int) -> int:
    return check_int(address, "address", 0, 255)


def _check_data(data: bytes) -> bytes:
    # bytes(3) would be three zero bytes and bytes("x") a TypeError: accept
    # only byte buffers, so a wrong argument is a clear fap_py error.
    return check_bytes(data, "data of a mikroC frame", 0, MAX_DATA)


def encode(address: int, data: bytes = b"", *, from_master: bool = True) -> bytes:
    """The frame carrying ``data`` (0..3 bytes) to (master) or from (slave)
    ``address``, escaped and checksummed by the C codec."""
    _check_address(address)
    data = _check_data(data)
    check_bool(from_master, "from_master")
    out = ffi.new("uint8_t[]", lib.MIKROC_RS485_FRAME_MAX)
    n = lib.mikrocRS485_Encode(out, data, len(data), address, 1 if from_master else 0)
    if n < 0:
        raise error_from_code(n, "mikroC encode")
    return bytes(ffi.buffer(out, n))


class Decoder:
    """Byte-wise decoder (the C state machine). Bytes outside frames are
    skipped; a 0x96 always starts a new frame."""

    def __init__(self) -> None:
        self._dec = ffi.new("mikrocRS485_decoder *")
        self._frame = ffi.new("mikrocRS485_frame *")
        lib.mikrocRS485_DecoderInit(self._dec)

    def reset(self) -> None:
        """Forget a half-received frame."""
        lib.mikrocRS485_DecoderInit(self._dec)

    def feed(self, data: bytes) -> List[Union[Message, MikrocFrameError]]:
        """Feed received bytes; return the frames and frame errors they
        completed, in order (errors are returned, not raised)."""
        events: List[Union[Message, MikrocFrameError]] = []
        f = self._frame
        for byte in check_bytes(data, "data", 0, 1 << 62):
            r = lib.mikrocRS485_DecoderFeed(self._dec, byte, f)
            if r == lib.MIKROC_RS485_MORE:
                continue
            if r == lib.MIKROC_RS485_FRAME:
                events.append(Message(f.address, bytes(f.data[0:f.count]),
                                      bool(f.datalen & lib.MIKROC_RS485_DL_MASTER)))
            else:
                events.append(_frame_error(r, f.address if f.header else None))
        return events


def decode(frame: bytes) -> Message:
    """Decode exactly one complete frame; raise its error otherwise."""
    frame = check_bytes(frame, "frame", 0, 1 << 62)
    events = Decoder().feed(frame)
    if len(events) == 1 and isinstance(events[0], Message):
        msg = events[0]
        # the decoder skips noise around a frame: exactly one frame means the
        # input is that frame's bytes and nothing else
        if encode(msg.address, msg.data, from_master=msg.from_master) == frame:
            return msg
    for e in events:
        if isinstance(e, MikrocFrameError):
            raise e
    raise FrameError(f"not exactly one mikroC frame: {frame.hex()}")
