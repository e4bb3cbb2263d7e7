"""pcap output: one record per frame, good or bad (docs/monitor.md).

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
from typing import BinaryIO, Optional

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



def __getattr__(name: str) -> object:
    """``PROTOCOL_IDS`` (deprecated): the pcap ids are the protocol table's."""
    if name == "PROTOCOL_IDS":
        import warnings

        warnings.warn("fap_py.monitor.pcap.PROTOCOL_IDS: use fap_py._protocols.get(name).pcap_id",
                      DeprecationWarning, stacklevel=2)
        return {p.name: p.pcap_id for p in _protocols.all_protocols()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["LINKTYPE", "PcapWriter", "header"]
