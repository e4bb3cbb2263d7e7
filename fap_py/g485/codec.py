"""G485 (Gicren G485_V11) frames, sans-I/O: encoders, a strict decoder and a
streaming parser.

Frame: ``FF FF | ADDRESS | LENGTH | PID | DATA... | CHECK`` where ADDRESS is
``(address << 1) | R/W`` (W = 0, R = 1), LENGTH counts every byte after it
(PID, data and check) and CHECK = ``~(ADDRESS + LENGTH + PID + DATA...) & 0xFF``.
The master's address is 127, so every reply starts ``FF FF FF``; the third
0xFF is an address byte, never a start byte.

Nothing here touches a file descriptor: the parser takes bytes and returns
events (:class:`Packet` or :class:`Discarded`).
"""
from __future__ import annotations

import enum
from typing import List, NamedTuple, Optional, Sequence, Tuple, Union

from .errors import (  # noqa: F401 - the codec's names since 0.1
    BroadcastReadError,
    CheckByteError,
    ErrorBit,
    G485FrameError,
    G485ValueError,
    UnexpectedReplyError,
    describe_error_word,
)

START = b"\xff\xff"
MASTER_ADDRESS = 127
BROADCAST = 0
MIN_SLAVE_ADDRESS = 1
MAX_SLAVE_ADDRESS = 126
SMA_R = (MASTER_ADDRESS << 1) | 1  # 0xFF: the address byte of every reply
MIN_REGISTER = 1
MAX_REGISTER = 100
HPID = 0x7F  # handshake
EPID = 0x7E  # get error word
#: LENGTH of the longest frame: PID + 100 data bytes + CHECK
MAX_LENGTH = MAX_REGISTER + 2
MIN_LENGTH = 2
#: bytes before the LENGTH byte is known: FF FF ADDRESS LENGTH
HEADER_SIZE = 4
#: what the vendor's manuals send to wake a device that detects the baud rate
WAKE_UP_PREAMBLE = b"\xff\xff\xff\xff"
#: the seed: devices above this baud rate lose the first packet after power-on
WAKE_UP_BAUD_THRESHOLD = 28800


class SetCommand(enum.IntEnum):
    """The ten Set sub-types (SPID values)."""

    FACTORY_RESET = 0x7D
    SAVE_EEPROM = 0x7C
    RESET = 0x7B
    CLEAR_ERROR_WORD = 0x7A
    REAL_TIME_WRITE = 0x79
    NON_REAL_TIME_WRITE = 0x78
    APPLY_WRITES = 0x77  # perform the pending Non-Real-Time writes
    CONTROL_MODE = 0x76
    BULK_MODE = 0x75
    LOCK_BAUD_RATE = 0x74


_SET_VALUES = frozenset(int(c) for c in SetCommand)


class PacketKind(enum.Enum):
    """The 8 instruction packet types of the seed."""

    WRITE = "User-Register-Write"
    READ_REQUEST = "User-Register-Read-Request"
    READ_RESPONSE = "User-Register-Read-Response"
    HANDSHAKE_REQUEST = "Handshake-Request"
    HANDSHAKE_RESPONSE = "Handshake-Response"
    ERROR_WORD_REQUEST = "Get-Error-Word-Request"
    ERROR_WORD_RESPONSE = "Get-Error-Word-Response"
    SET = "Set"


REPLY_KINDS = frozenset({PacketKind.READ_RESPONSE, PacketKind.HANDSHAKE_RESPONSE,
                         PacketKind.ERROR_WORD_RESPONSE})


class Packet(NamedTuple):
    """A decoded, check-verified frame.

    ``address`` is the 7-bit slave address (0 = broadcast) for requests and
    127 for replies; ``pid`` the register (RPID) or 0x7F/0x7E/Set value.
    """

    kind: PacketKind
    address: int
    pid: int
    data: bytes
    check: int
    raw: bytes

    @property
    def register(self) -> int:
        """First register of a write, read request or read response."""
        return self.pid

    @property
    def read_count(self) -> int:
        """RCBN of a read request, else the number of data bytes."""
        if self.kind is PacketKind.READ_REQUEST:
            return self.data[0]
        return len(self.data)

    @property
    def command(self) -> SetCommand:
        """The sub-type of a Set packet."""
        return SetCommand(self.pid)

    @property
    def error_word(self) -> int:
        """ERRH << 8 | ERRL of a Get-Error-Word-Response."""
        return (self.data[0] << 8) | self.data[1]

    @property
    def handshake_value(self) -> int:
        """The SDOC/SDIC byte carried by a Handshake-Response."""
        return self.data[0]


class ParseIssue(enum.Enum):
    """Why the parser dropped bytes."""

    GARBAGE = "bytes outside any frame"
    BAD_LENGTH = "start bytes followed by an impossible address/length"
    BAD_CHECK = "check byte does not match"
    UNKNOWN_PACKET = "valid check byte but no G485 packet type fits PID/length/address"
    STALE = "incomplete frame expired (line idle)"


class Discarded(NamedTuple):
    """Bytes the parser dropped, and why.

    For ``BAD_CHECK`` ``data`` is the whole candidate frame; the parser then
    resynchronises from the candidate's second byte (a corrupted length byte
    must not swallow the next frame), so its later bytes may be reported
    again as garbage.
    """

    data: bytes
    issue: ParseIssue
    detail: str


Event = Union[Packet, Discarded]
#: register data: bytes-like, a sequence of ints 0..255, or one int
Data = Union[bytes, bytearray, memoryview, Sequence[int], int]


def _raw(data: bytes, what: str) -> bytes:
    """``data`` as bytes when it is bytes-like (the hot paths pass bytes: one type test)."""
    if type(data) is bytes:
        return data
    if isinstance(data, (bytearray, memoryview)):
        return bytes(data)
    raise G485ValueError(f"{what} must be bytes-like, not {type(data).__name__}")


def _buffer_bytes(data: object, what: str) -> bytes:
    """The bytes of any bytes-like object (buffer protocol, C-contiguous or not)."""
    if isinstance(data, str):
        raise G485ValueError(f"{what} takes bytes, not str (encode it first)")
    try:
        return memoryview(data).tobytes()          # type: ignore[arg-type]
    except TypeError:
        raise G485ValueError(f"{what} takes bytes, not {type(data).__name__}") from None
    except ValueError as exc:                      # a released memoryview
        raise G485ValueError(f"{what}: unusable buffer ({exc})") from None


def _u8s(*values: int) -> None:
    """Raw header fields: ints 0..255 (not bools)."""
    for v in values:
        if type(v) is not int or not 0 <= v <= 0xFF:
            raise G485ValueError(f"a header field is a byte value 0..255, not {v!r}")


def check_byte(body: bytes) -> int:
    """CHECK of ADDRESS..DATA (the frame without FF FF and without CHECK)."""
    return ~sum(_raw(body, "body")) & 0xFF


def frame(address_byte: int, pid: int, data: bytes = b"") -> bytes:
    """A frame from its raw fields, not checked against the protocol (the encoders
    below validate first); only their types and byte ranges are."""
    data = _raw(data, "data")
    _u8s(address_byte, pid, len(data) + 2)
    body = bytes((address_byte, len(data) + 2, pid)) + data
    return START + body + bytes((check_byte(body),))


_frame = frame

#: ``sum(frame) & 0xFF`` of every frame (FF FF included) whose check byte is right:
#: ADDRESS..DATA plus ``~(ADDRESS..DATA) & 0xFF`` is 0xFF (mod 256) and FF FF adds 0x1FE.
#: The fast paths check a whole frame with it, without slicing.
FRAME_SUM = (0xFF + 2 * 0xFF) & 0xFF


# -- fast paths: the common frames recognised whole --------------------------

def reply_prefix(pid: int, length: int) -> bytes:
    """The first 5 bytes of the reply a master awaits: ``FF FF FF LENGTH PID``.

    A chunk read from the port that starts with them, is ``HEADER_SIZE +
    length`` bytes long and sums to :data:`FRAME_SUM` is exactly the reply
    the :class:`Parser` would return (see :func:`is_exact_reply`).
    """
    _u8s(pid, length)
    return START + bytes((SMA_R, length, pid))


def is_exact_reply(chunk: bytes, prefix: bytes) -> bool:
    """True if ``chunk`` is exactly one well-checked reply starting with ``prefix`` (from :func:`reply_prefix`).

    ``prefix`` must come from a valid request (its PID and LENGTH fit a reply
    type), so no further classification is needed.
    """
    if type(chunk) is not bytes or type(prefix) is not bytes:
        chunk, prefix = _raw(chunk, "chunk"), _raw(prefix, "prefix")
    if len(prefix) != len(START) + 3:
        raise G485ValueError(f"prefix must be the 5 bytes of reply_prefix(), not {prefix!r}")
    return (len(chunk) == HEADER_SIZE + prefix[3] and chunk.startswith(prefix)
            and sum(chunk) & 0xFF == FRAME_SUM)


def _prefix_of(prefix: bytes) -> bytes:
    """``prefix`` if it is the 5 bytes of a :func:`reply_prefix` (one type test on the hot path)."""
    if type(prefix) is not bytes:
        prefix = _raw(prefix, "prefix")
    if len(prefix) != len(START) + 3 or not prefix.startswith(START):
        raise G485ValueError(f"prefix must be the 5 bytes of reply_prefix(), not {prefix!r}")
    return prefix


def _frame_of(frame: bytes) -> bytes:
    """``frame`` if it is bytes of a whole frame's length (its LENGTH byte agrees)."""
    if type(frame) is not bytes:
        frame = _raw(frame, "frame")
    if len(frame) < HEADER_SIZE + MIN_LENGTH or frame[3] + HEADER_SIZE != len(frame):
        raise G485ValueError(f"not a whole G485 frame: {frame.hex(' ')}")
    return frame


def reply_size(prefix: bytes) -> int:
    """Bytes of the whole reply a :func:`reply_prefix` announces."""
    return HEADER_SIZE + _prefix_of(prefix)[3]


def prefix_pid(prefix: bytes) -> int:
    """The PID (register, HPID or EPID) of the reply a :func:`reply_prefix` announces."""
    return _prefix_of(prefix)[4]


_REPLY_KIND = {HPID: PacketKind.HANDSHAKE_RESPONSE, EPID: PacketKind.ERROR_WORD_RESPONSE}


def reply_packet(frame: bytes) -> Packet:
    """The :class:`Packet` of a reply frame already checked against its prefix
    (:func:`is_exact_reply` or the :class:`Parser`): no second classification."""
    frame = _frame_of(frame)
    return Packet(_REPLY_KIND.get(frame[4], PacketKind.READ_RESPONSE), MASTER_ADDRESS, frame[4],
                  frame[5:-1], frame[-1], frame)


def frame_check(frame: bytes) -> int:
    """The CHECK byte of an encoded frame (a request's MDOC/MDIC)."""
    return _frame_of(frame)[-1]


def exact_packet(chunk: bytes) -> Optional[Packet]:
    """The packet if ``chunk`` is exactly one well-checked G485 frame, else None.

    The simulator's fast path for a chunk read while nothing is buffered:
    for such a chunk the :class:`Parser` would return this one Packet and
    keep nothing; for anything else (None) the Parser decides.
    """
    if type(chunk) is not bytes:
        chunk = _raw(chunk, "chunk")
    n = len(chunk)
    if n < HEADER_SIZE + MIN_LENGTH or n > HEADER_SIZE + MAX_LENGTH or not chunk.startswith(START):
        return None
    length = chunk[3]
    if length + HEADER_SIZE != n or chunk[2] == 0xFE or sum(chunk) & 0xFF != FRAME_SUM:
        return None
    kind = classify(chunk[2], length, chunk[4])
    return None if kind is None else _packet(kind, chunk)


def frame_start(chunk: bytes) -> bool:
    """True if ``chunk`` is the unfinished start of a request frame that a
    :class:`Parser` holding nothing would keep whole and report nothing for.

    The simulator's fast path for a request read in pieces: it holds such a
    chunk as bytes and tries :func:`exact_packet` on the joined pieces; the
    Parser, fed the joined bytes at once, decides everything else exactly as
    it would have piece by piece. FF FF FF (a reply or the wake-up preamble)
    is never held: the Parser looks ahead there.
    """
    if type(chunk) is not bytes:
        chunk = _raw(chunk, "chunk")
    n = len(chunk)
    if n < 3:
        return n > 0 and START.startswith(chunk)
    if not chunk.startswith(START) or chunk[2] == SMA_R or chunk[2] == 0xFE:
        return False
    return n == 3 or MIN_LENGTH <= chunk[3] <= MAX_LENGTH and n < HEADER_SIZE + chunk[3]


# -- argument checks ---------------------------------------------------------

def _check_address(address: int, *, broadcast_ok: bool, what: str) -> None:
    if not isinstance(address, int) or isinstance(address, bool):
        raise G485ValueError(f"address must be an int, got {address!r}")
    if address == BROADCAST:
        if broadcast_ok:
            return
        raise BroadcastReadError(
            f"{what} cannot be broadcast: G485 allows only User-Register-Write and Set "
            f"on address 0 (nobody may answer a broadcast)")
    if not MIN_SLAVE_ADDRESS <= address <= MAX_SLAVE_ADDRESS:
        raise G485ValueError(f"slave address {address} outside 1..126"
                             + (" (0 = broadcast)" if broadcast_ok else ""))


def check_register_span(register: int, count: int) -> None:
    """Raise G485ValueError unless registers register..register+count-1 lie in 1..100."""
    if (isinstance(register, bool) or not isinstance(register, int)
            or not MIN_REGISTER <= register <= MAX_REGISTER):
        raise G485ValueError(f"register {register!r} outside 1..100")
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise G485ValueError(f"register count {count!r}: at least 1 register")
    if register + count - 1 > MAX_REGISTER:
        raise G485ValueError(f"registers {register}..{register + count - 1} run past 100")


def _as_data(data: Data) -> bytes:
    if isinstance(data, int) and not isinstance(data, bool):
        data = [data]
    elif isinstance(data, (list, tuple)):
        if any(isinstance(v, bool) for v in data):
            raise G485ValueError("register data must be ints 0..255, not bools")
    elif not isinstance(data, (bytes, bytearray, memoryview)):
        raise G485ValueError(f"register data must be bytes, ints 0..255 or one int, "
                             f"not {type(data).__name__}")
    if isinstance(data, (list, tuple)):
        bad = [v for v in data if not isinstance(v, int) or not 0 <= v <= 255]
        if bad:
            raise G485ValueError(f"register data must be bytes or ints 0..255, not {bad[0]!r}")
    return bytes(data)


# -- encoders (the 8 packet types) -------------------------------------------

def encode_write(address: int, register: int, data: Data) -> bytes:
    """User-Register-Write (address 0 = broadcast)."""
    _check_address(address, broadcast_ok=True, what="write")
    payload = _as_data(data)
    check_register_span(register, len(payload) or 0)
    return _frame(address << 1, register, payload)


def encode_read_request(address: int, register: int, count: int) -> bytes:
    """User-Register-Read-Request for ``count`` (RCBN) registers."""
    _check_address(address, broadcast_ok=False, what="a register read")
    check_register_span(register, count)
    return _frame((address << 1) | 1, register, bytes((count,)))


def encode_read_response(register: int, data: Data) -> bytes:
    """User-Register-Read-Response (slave to master)."""
    payload = _as_data(data)
    check_register_span(register, len(payload) or 0)
    return _frame(SMA_R, register, payload)


def _pid_request(address: int, pid: int, what: str) -> bytes:
    """A read of one special PID (handshake, error word) from one device."""
    _check_address(address, broadcast_ok=False, what=what)
    return _frame((address << 1) | 1, pid)


def _pid_response(pid: int, value: int, size: int, what: str, top: str) -> bytes:
    """The answer to :func:`_pid_request`: ``value`` in ``size`` bytes, high byte first."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << (8 * size):
        raise G485ValueError(f"{what} {value} outside 0..{top}")
    return _frame(SMA_R, pid, value.to_bytes(size, "big"))


def encode_handshake_request(address: int) -> bytes:
    """Handshake-Request."""
    return _pid_request(address, HPID, "a handshake")


def encode_handshake_response(value: int) -> bytes:
    """Handshake-Response carrying the slave's SDOC/SDIC."""
    return _pid_response(HPID, value, 1, "handshake value", "255")


def encode_error_word_request(address: int) -> bytes:
    """Get-Error-Word-Request."""
    return _pid_request(address, EPID, "an error-word read")


def encode_error_word_response(word: int) -> bytes:
    """Get-Error-Word-Response, ERRH first."""
    return _pid_response(EPID, word, 2, "error word", "0xffff")


def encode_set(address: int, command: Union[SetCommand, int, str]) -> bytes:
    """Set (address 0 = broadcast); ``command`` a SetCommand, its value or name."""
    _check_address(address, broadcast_ok=True, what="set")
    return _frame(address << 1, int(set_command(command)))


def set_command(command: Union[SetCommand, int, str]) -> SetCommand:
    """A SetCommand from a member, a value 0x74..0x7D or a name (any case)."""
    if isinstance(command, SetCommand):
        return command
    if isinstance(command, str):
        try:
            return SetCommand[command.upper()]
        except KeyError:
            raise G485ValueError(f"unknown Set command {command!r}; one of "
                                 f"{', '.join(c.name for c in SetCommand)}") from None
    try:
        return SetCommand(command)
    except ValueError:
        raise G485ValueError(f"Set command {command!r} outside 0x74..0x7d") from None


# -- classification and strict decoding --------------------------------------

def classify(address_byte: int, length: int, pid: int) -> Optional[PacketKind]:
    """The packet type a well-checked frame header denotes, or None."""
    _u8s(address_byte, length, pid)
    if address_byte == SMA_R:
        if MIN_REGISTER <= pid <= MAX_REGISTER:
            if length >= 3 and pid + length - 3 <= MAX_REGISTER:
                return PacketKind.READ_RESPONSE
            return None
        if pid == HPID:
            return PacketKind.HANDSHAKE_RESPONSE if length == 3 else None
        if pid == EPID:
            return PacketKind.ERROR_WORD_RESPONSE if length == 4 else None
        return None
    if address_byte & 1:
        if MIN_REGISTER <= pid <= MAX_REGISTER:
            return PacketKind.READ_REQUEST if length == 3 else None
        if pid == HPID:
            return PacketKind.HANDSHAKE_REQUEST if length == 2 else None
        if pid == EPID:
            return PacketKind.ERROR_WORD_REQUEST if length == 2 else None
        return None
    if address_byte == (MASTER_ADDRESS << 1):
        return None  # nobody writes to the master
    if MIN_REGISTER <= pid <= MAX_REGISTER:
        if length >= 3 and pid + length - 3 <= MAX_REGISTER:
            return PacketKind.WRITE
        return None
    if pid in _SET_VALUES:
        return PacketKind.SET if length == 2 else None
    return None


def _packet(kind: PacketKind, frame: bytes) -> Packet:
    return Packet(kind, frame[2] >> 1, frame[4], frame[5:-1], frame[-1], frame)


def decode_frame(frame: bytes) -> Packet:
    """Decode exactly one frame; raise a G485FrameError subclass saying what is wrong."""
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise G485ValueError(f"a frame is bytes, not {type(frame).__name__}")
    frame = bytes(frame)
    if len(frame) < HEADER_SIZE + MIN_LENGTH or frame[:2] != START:
        raise G485FrameError(f"not a G485 frame (must start FF FF, at least 6 bytes): {frame.hex(' ')}")
    length = frame[3]
    if length + HEADER_SIZE != len(frame):
        raise G485FrameError(f"length byte {length} but {len(frame) - HEADER_SIZE} bytes follow it")
    expected = check_byte(frame[2:-1])
    if expected != frame[-1]:
        raise CheckByteError(f"bad check byte 0x{frame[-1]:02x}, expected 0x{expected:02x}: "
                             f"{frame.hex(' ')}", frame)
    kind = classify(frame[2], length, frame[4])
    if kind is None:
        raise UnexpectedReplyError(f"no G485 packet type has address byte 0x{frame[2]:02x}, "
                                   f"length {length}, PID 0x{frame[4]:02x}")
    return _packet(kind, frame)


# -- streaming parser ---------------------------------------------------------

class Parser:
    """Streaming G485 parser: feed bytes, get packets and discards.

    It looks for FF FF with ``bytes.find``, takes the next byte as the
    address (even if it is 0xFF), checks the length byte, waits for the
    whole frame, then checks the check byte. Anything that fails is reported
    as :class:`Discarded` and the search restarts one byte later. A partial
    frame whose rest never comes is dropped by :meth:`expire`, which the
    I/O layer calls when the line has been idle.
    """

    __slots__ = ("_buf",)

    def __init__(self) -> None:
        self._buf = bytearray()

    def clear(self) -> None:
        """Forget buffered bytes."""
        del self._buf[:]

    @property
    def buffered(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def pending_header(self) -> Optional[Tuple[int, int]]:
        """(address byte, length byte) of the partial frame held, if known."""
        buf = self._buf
        if len(buf) >= HEADER_SIZE:
            return buf[2], buf[3]
        return None

    def bytes_wanted(self) -> int:
        """Bytes still needed to finish the held partial frame (or its header); 0 if none held."""
        n = len(self._buf)
        if n == 0:
            return 0
        if n < HEADER_SIZE:
            return HEADER_SIZE - n
        return HEADER_SIZE + self._buf[3] - n

    def feed(self, data: bytes) -> List[Event]:
        """Add bytes; return the packets and discards they complete, in order.

        ``data``: any bytes-like object (bytes, bytearray, a memoryview, strided
        or multi-dimensional ones too, an ``array``, ``mmap``); a str, an int
        or a released memoryview is a :class:`G485ValueError`."""
        if not isinstance(data, (bytes, bytearray)):
            data = _buffer_bytes(data, "feed")
        buf = self._buf
        buf += data
        events: List[Event] = []
        n = len(buf)
        pos = 0
        while True:
            i = buf.find(START, pos)
            if i < 0:
                # a trailing 0xFF may be the first start byte of the next frame
                end = n - 1 if n > pos and buf[n - 1] == 0xFF else n
                if end > pos:
                    events.append(Discarded(bytes(buf[pos:end]), ParseIssue.GARBAGE,
                                            f"{end - pos} byte(s) without FF FF"))
                pos = end
                break
            if i > pos:
                events.append(Discarded(bytes(buf[pos:i]), ParseIssue.GARBAGE,
                                        f"{i - pos} byte(s) before FF FF"))
                pos = i
            if n - i < HEADER_SIZE:
                break
            length = buf[i + 3]
            if length < MIN_LENGTH or length > MAX_LENGTH or buf[i + 2] == 0xFE:
                events.append(Discarded(bytes(buf[i:i + 1]), ParseIssue.BAD_LENGTH,
                                        f"address byte 0x{buf[i + 2]:02x} length {length}"))
                pos = i + 1
                continue
            end = i + HEADER_SIZE + length
            if buf[i + 2] == SMA_R and 0 < self._request_end(i + 1) <= end:
                # FF FF FF LEN is a reply header only if nothing better fits: after the
                # wake-up preamble (FF FF FF FF) it is the request FF FF ADDR starting one
                # byte later, complete and well-checked, that this header swallows. The
                # request must end no later than the reply would: then the choice is the
                # same however the bytes arrive (whole, in chunks or one by one).
                events.append(Discarded(bytes(buf[i:i + 1]), ParseIssue.GARBAGE,
                                        "0xff before a request (wake-up preamble)"))
                pos = i + 1
                continue
            if end > n:
                break
            frame = bytes(buf[i:end])
            expected = check_byte(frame[2:-1])
            if expected != frame[-1]:
                events.append(Discarded(frame, ParseIssue.BAD_CHECK,
                                        f"check 0x{frame[-1]:02x}, expected 0x{expected:02x}"))
                pos = i + 1
                continue
            kind = classify(frame[2], length, frame[4])
            if kind is None:
                events.append(Discarded(frame, ParseIssue.UNKNOWN_PACKET,
                                        f"address byte 0x{frame[2]:02x} length {length} "
                                        f"PID 0x{frame[4]:02x}"))
            else:
                events.append(_packet(kind, frame))
            pos = end
        if pos:
            del buf[:pos]
        return events

    def _request_end(self, j: int) -> int:
        """The end offset of a whole, well-checked request frame starting at buffer
        offset ``j``; 0 if there is none (yet)."""
        buf = self._buf
        if len(buf) - j < HEADER_SIZE + MIN_LENGTH or buf[j:j + 2] != START or buf[j + 2] == SMA_R:
            return 0
        length = buf[j + 3]
        end = j + HEADER_SIZE + length
        if length < MIN_LENGTH or length > MAX_LENGTH or end > len(buf):
            return 0
        frame = bytes(buf[j:end])
        ok = check_byte(frame[2:-1]) == frame[-1] and classify(frame[2], length, frame[4]) is not None
        return end if ok else 0

    def expire(self) -> List[Event]:
        """The line went idle: drop held partial frames byte by byte, re-parsing the rest."""
        events: List[Event] = []
        while self._buf:
            events.append(Discarded(bytes(self._buf[:1]), ParseIssue.STALE,
                                    f"{len(self._buf)} byte(s) of an unfinished frame"))
            del self._buf[:1]
            events.extend(self.feed(b""))
        return events
