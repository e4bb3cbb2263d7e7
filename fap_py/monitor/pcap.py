"""pcap output and input: one record per frame, good or bad (docs/monitor.md).

Link type LINKTYPE_USER0 (147). Each packet is a small header, then the
frame's bytes exactly as they were on the wire:

    offset  size  field
    0       1     version (1)
    1       1     protocol: its pcap id in the protocol table (fap_py._protocols:
                  1 fap, 2 exec async, 3 mikroC, 4 G485)
    2       1     flags: bit 0 frame ok, bit 1 port known, bit 2 time known
    3       1     sender port (0xff when unknown)
    4       1     L, length of the text
    5       L     text, ASCII: a bad frame's error reason ("crc", "garbage",
                  ...); a good frame's message type name as the monitor
                  decoded it (its plug-in's label: FAP msg_name, G485 packet),
                  else empty
    5+L     ...   the frame

Records without a time get the time of the previous one (0 at first).
"""
from __future__ import annotations

import errno
import io
import struct
from typing import BinaryIO, Iterator, NamedTuple, Optional

from .. import _protocols
from .._closing import Closing
from .._validate import check_bool
from ..errors import FileError, InvalidTypeError, InvalidValueError
from .core import Record
from .decoders import plugin

LINKTYPE = 147           # LINKTYPE_USER0 / DLT_USER0
HEADER_VERSION = 1
FLAG_OK, FLAG_PORT, FLAG_TIME = 1, 2, 4
SNAPLEN = 65535
_GLOBAL = struct.Struct("<IHHiIII")
_RECORD = struct.Struct("<IIII")
_T_LAST = 2.0**32 - 1e-6      # the last time a pcap record holds


def header(rec: Record) -> bytes:
    """The per-packet header described above."""
    if not isinstance(rec, Record):
        raise InvalidTypeError(f"rec must be a Record, not {type(rec).__name__}")
    flags = (FLAG_OK if rec.ok else 0) | (FLAG_PORT if rec.port is not None else 0) \
        | (FLAG_TIME if rec.t is not None else 0)
    text: Optional[str] = rec.error
    if text is None and rec.fields:
        label = getattr(plugin(rec.protocol), "label", None)    # optional: a message type
        text = label(rec.event) if label else None
    reason = (text or "").encode("ascii")[:255]
    port = 0xFF if rec.port is None else rec.port & 0xFF
    pcap_id = _protocols.get(rec.protocol).pcap_id
    return bytes((HEADER_VERSION, pcap_id, flags, port, len(reason))) + reason


class PcapWriter(Closing):
    """Writes records to a pcap file (a context manager)."""

    def __init__(self, fh: BinaryIO, epoch: Optional[float] = None) -> None:
        """``fh``: a binary file open for writing; ``epoch``: the time of untimed records.

        A text file (``open(path, "w")``, ``io.StringIO``) is an
        :class:`InvalidTypeError`, a closed file or one not open for writing an
        :class:`InvalidValueError`, a failed write of the file header a
        :class:`FileError`: all here, before any record."""
        if not callable(getattr(fh, "write", None)) or not callable(getattr(fh, "flush", None)):
            raise InvalidTypeError(f"fh must be a binary file, not {type(fh).__name__}")
        if isinstance(fh, io.TextIOBase):
            raise InvalidTypeError(f"fh must be a binary file (open it with 'wb'), not a text file "
                                   f"({type(fh).__name__})")
        if epoch is not None and (isinstance(epoch, bool) or not isinstance(epoch, (int, float))
                                  or not 0.0 <= epoch < 2.0**32):
            raise InvalidValueError(f"epoch must be None or 0..2**32 s, not {epoch!r}")
        self._fh = fh
        self._last = 0.0 if epoch is None else epoch
        try:
            fh.write(_GLOBAL.pack(0xA1B2C3D4, 2, 4, 0, 0, SNAPLEN, LINKTYPE))
            fh.flush()
        except TypeError:             # a text file that is no io.TextIOBase
            raise InvalidTypeError(f"fh must be a binary file (open it with 'wb'): "
                                   f"{type(fh).__name__} does not take bytes") from None
        except io.UnsupportedOperation:
            raise InvalidValueError("fh is not open for writing (open it with 'wb')") from None
        except ValueError as exc:     # closed
            raise InvalidValueError(f"fh cannot be written: {exc}") from None
        except OSError as exc:
            raise FileError(exc.errno or errno.EIO, f"pcap file: {exc.strerror or exc}",
                            getattr(fh, "name", None) if isinstance(getattr(fh, "name", None), str)
                            else None) from None

    def write(self, rec: Record, flush: bool = False) -> None:
        """Append one record. A pcap record holds 0 <= t < 2**32 s: a later time
        (a capture's last second plus its bytes' wire time) is written as the last
        microsecond it holds."""
        check_bool(flush, "flush")
        if not isinstance(rec, Record):
            raise InvalidTypeError(f"rec must be a Record, not {type(rec).__name__}")
        t = self._last if rec.t is None else min(rec.t, _T_LAST)
        self._last = t
        sec = int(t)
        usec = int(round((t - sec) * 1e6))
        if usec >= 1_000_000:
            sec, usec = sec + 1, usec - 1_000_000
        payload = header(rec) + rec.raw
        n = min(len(payload), SNAPLEN)
        self._fh.write(_RECORD.pack(sec, usec, n, len(payload)) + payload[:n])
        if flush:
            self._fh.flush()

    def flush(self) -> None:
        self._fh.flush()

    def close(self) -> None:
        self._fh.flush()



class PcapFrame(NamedTuple):
    """One packet of a monitor pcap, as :func:`read_pcap` gives it back."""

    t: float                 #: seconds (the record's timestamp)
    protocol: str            #: the protocol table's name of its pcap id
    ok: bool                 #: the monitor decoded it as a good frame
    port: Optional[int]      #: the sender port, when known
    text: str                #: the error reason or message type the monitor wrote
    raw: bytes               #: the frame's bytes as they were on the wire


#: the pcap magics: microsecond and nanosecond timestamps, each byte order
_MAGICS = {b"\xd4\xc3\xb2\xa1": ("<", 1e-6), b"\xa1\xb2\xc3\xd4": (">", 1e-6),
           b"\x4d\x3c\xb2\xa1": ("<", 1e-9), b"\xa1\xb2\x3c\x4d": (">", 1e-9)}


def is_pcap(path: str) -> bool:
    """True when the file at ``path`` starts with a pcap magic (else it may be a vbus capture)."""
    from .._validate import check_path

    path = check_path(path, "path")     # never an int: open(3) would take over fd 3
    try:
        with open(path, "rb") as fh:
            return fh.read(4) in _MAGICS
    except OSError:
        return False


def read_pcap(path: str) -> Iterator[PcapFrame]:
    """The frames of a pcap the monitor wrote (link type 147, the header above), in file
    order. Not a pcap, another link type: :class:`FileError` here, at the call; a packet with
    a header of another version or an unknown protocol id: :class:`FileError` naming the
    packet, while iterating; a file cut in the middle of its last packet ends there (the
    monitor may be writing it)."""
    from .._validate import check_path

    path = check_path(path, "path")
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise FileError(exc.errno or errno.EIO, f"pcap file: {exc.strerror}", path) from None
    try:
        head = fh.read(24)
        if len(head) < 24 or head[:4] not in _MAGICS:
            raise _not_pcap(path, "no pcap file header")
        order, unit = _MAGICS[head[:4]]
        linktype = struct.unpack(order + "I", head[20:24])[0] & 0x0FFFFFFF
        if linktype != LINKTYPE:
            raise _not_pcap(path, f"link type {linktype}, not the monitor's {LINKTYPE} "
                            "(fap monitor --pcap writes it)")
    except BaseException:
        fh.close()
        raise
    return _packets(fh, path, order, unit)


def _not_pcap(path: str, what: str) -> FileError:
    return FileError(errno.EINVAL, f"not a monitor pcap: {what}", path)


def _packets(fh: BinaryIO, path: str, order: str, unit: float) -> Iterator[PcapFrame]:
    by_id = {p.pcap_id: p.name for p in _protocols.all_protocols()}
    rec = struct.Struct(order + "IIII")
    n = 0
    with fh:
        while True:
            h = fh.read(16)
            if len(h) < 16:
                return
            sec, frac, incl, _orig = rec.unpack(h)
            if incl > SNAPLEN:
                raise _not_pcap(path, f"packet {n + 1} claims {incl} bytes (more than the snap length)")
            data = fh.read(incl)
            if len(data) < incl:
                return
            n += 1
            if len(data) < 5 or data[0] != HEADER_VERSION or len(data) < 5 + data[4]:
                raise _not_pcap(path, f"packet {n} has no version-{HEADER_VERSION} monitor header")
            name = by_id.get(data[1])
            if name is None:
                raise _not_pcap(path, f"packet {n} has protocol id {data[1]}, which the protocol "
                                "table does not hold")
            flags, port, tl = data[2], data[3], data[4]
            yield PcapFrame(sec + frac * unit, name, bool(flags & FLAG_OK),
                            port if flags & FLAG_PORT else None,
                            data[5:5 + tl].decode("ascii", "replace"), bytes(data[5 + tl:]))


__all__ = ["LINKTYPE", "PcapWriter", "header"]
