"""Virtual multi-drop RS-485 bus for tests, demos and benchmarks.

:class:`VirtualBus` wraps libfap's C bus (``include/fap_vbus.h``): N
pseudo-terminal ports that behave as one 2-wire bus. Every byte written on
one port reaches every other port (and the sender too with ``echo=True``).
With ``baud`` set, delivery is paced at 10 bits per byte and overlapping
transmissions collide (both arrive bit-inverted). Faults are seeded and
reproducible. A relay thread in C does the copying, so Python code using the
bus (or a C program opened on one of :attr:`VirtualBus.paths`) runs freely.

:func:`read_capture` parses the capture file the bus writes with
``capture=PATH`` (format in ``docs/vbus.md``).

Example::

    with VirtualBus(ports=3, baud=9600) as bus:
        a, b, c = bus.paths          # open these like serial devices
"""
from __future__ import annotations

import errno
import fcntl
import logging
import os
import stat
import threading
from dataclasses import dataclass, field
from typing import Any, Dict, Iterable, Iterator, List, Optional, Union

from ._files import open_user_file
from ._handle import NativeHandle
from ._native import ffi, lib
from ._stats import Counters, stats_from_c
from ._validate import check_bool, check_int, check_path, check_probability, check_seconds
from .errors import FileError, InvalidTypeError, InvalidValueError, PortBusyError, error_from_code

__all__ = [
    "MAX_CAPTURE_BYTES",
    "MAX_PORTS",
    "Capture",
    "CaptureEvent",
    "CaptureFormatError",
    "CaptureRecord",
    "LINK_DIR_LOCK",
    "LinkDirBusyError",
    "VirtualBus",
    "VirtualBusStats",
    "parse_capture",
    "read_capture",
]

log = logging.getLogger(__name__)

MAX_PORTS: int = lib.FAP_VBUS_MAX_PORTS
_MAX_MS = 0xFFFFFFFF           # the C API takes unsigned milliseconds
_MAX_COUNT = 0xFFFFFFFF

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class VirtualBusStats(Counters):
    """Counters of a bus since it opened (``fap_vbus_stats``)."""

    bytes_in: int       #: bytes written by nodes
    bytes_out: int      #: bytes delivered to nodes
    collisions: int     #: overlapping transmissions (paced mode)
    bit_errors: int     #: bytes corrupted by fault injection
    dropped: int        #: bytes dropped by fault injection or silence
    overflow: int       #: bytes not delivered because a node did not read
    disconnects: int    #: simulated disconnects
    paced_bytes: int = 0        #: bytes delivered by the pacer (paced mode)
    pace_late_sum_ns: int = 0   #: their total lateness vs the end of their wire time
    pace_late_max_ns: int = 0   #: the worst lateness

    @property
    def pace_late_mean_us(self) -> float:
        """Mean pacer lateness in microseconds (0.0 when nothing was paced)."""
        return self.pace_late_sum_ns / self.paced_bytes / 1000.0 if self.paced_bytes else 0.0


def _check(code: int, what: str) -> int:
    if code < 0:
        raise error_from_code(code, what)
    return code


def _to_ms(seconds: float, what: str) -> int:
    return round(check_seconds(seconds, f"{what}: seconds", hi=_MAX_MS / 1000.0) * 1000.0)


#: the lock file a bus holds (``flock``, with its pid) in its ``link_dir``
LINK_DIR_LOCK = ".fap-bus.lock"


class LinkDirBusyError(PortBusyError):
    """Another live virtual bus holds the ``link_dir`` (its lock file):
    a second bus there would re-point the first one's links. ``pid`` is the
    holder's (None when its lock file holds no pid yet)."""

    def __init__(self, link_dir: str, pid: Optional[int]) -> None:
        who = f"pid {pid}" if pid is not None else "a process"
        super().__init__(errno.EBUSY, f"another virtual bus ({who}) is running on this "
                         "link directory; stop it or use another directory", link_dir)
        self.pid = pid


def _lock_pid(fd: int) -> Optional[int]:
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _lock_link_dir(link_dir: str) -> Optional[tuple]:
    """Take ``link_dir``'s bus lock (docs/vbus.md): create the directory if
    missing (its last component, as C does), ``flock`` the lock file and
    write our pid into it. A lock file whose process died holds no flock
    and is taken over. Returns (fd, created) to release with
    :func:`_unlock_link_dir`, or None when the directory cannot be made or
    used (C then reports the error as before). Raises LinkDirBusyError."""
    created = False
    try:
        os.mkdir(link_dir, 0o755)
        created = True
    except FileExistsError:
        pass
    except OSError:
        return None
    path = os.path.join(link_dir, LINK_DIR_LOCK)
    for _ in range(8):   # the holder may unlink the file between our open and flock
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
        except OSError:
            if created:
                os.rmdir(link_dir)
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid = _lock_pid(fd)
            os.close(fd)
            raise LinkDirBusyError(link_dir, pid) from None
        except OSError:
            os.close(fd)
            return None
        try:
            same = os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if not same:            # locked a file its holder just removed: again
            os.close(fd)
            continue
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            return None
        old = _lock_pid(fd)
        if old is not None and old != os.getpid():
            log.info("%s: taking over the lock of pid %d (no longer running)", link_dir, old)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        return fd, created
    return None


def _unlock_link_dir(link_dir: str, held: Optional[tuple]) -> None:
    """Remove the lock file and release it; remove the directory if we made it."""
    if held is None:
        return
    fd, created = held
    try:
        os.unlink(os.path.join(link_dir, LINK_DIR_LOCK))
    except OSError:
        pass
    os.close(fd)
    if created:
        try:
            os.rmdir(link_dir)
        except OSError:
            pass


class VirtualBus(NativeHandle):
    """A virtual RS-485 bus of ``ports`` pty ports (a context manager).

    Args:
        ports: number of ports, 2..64.
        baud: pace delivery at this rate (10 bits per byte) and detect
            collisions; ``None`` or 0 relays as fast as the ptys go.
        echo: also deliver each byte back to its sender.
        link_dir: directory for the stable port symlinks ``port0..``
            (created if missing); default a private temporary directory.
        capture: record every byte on the bus in this file.
        seed: seed of every random fault (runs with the same seed and the
            same traffic see the same faults).
        realtime: real-time spec of the relay thread (``"fifo:60,mlock"``,
            docs/realtime.md); refused without the privilege (RealTimeError).

    Raises:
        InvalidValueError: bad arguments.
        PortError: the ptys, symlinks or capture file could not be made.
    """

    _kind = "virtual bus"

    def __init__(self, ports: int = 3, baud: Optional[int] = None, echo: bool = False,
                 link_dir: Optional[PathLike] = None, capture: Optional[PathLike] = None,
                 seed: int = 0, realtime: Optional[str] = None) -> None:
        super().__init__()
        self._ffi, self._lib = ffi, lib
        self._lock = threading.Lock()
        check_int(ports, "ports", 2, MAX_PORTS)
        baud = 0 if baud is None else check_int(baud, "baud", 0, 10_000_000)
        check_bool(echo, "echo")
        check_int(seed, "seed", -(1 << 63), (1 << 64) - 1)
        # one check for both (C takes NUL-terminated strings: "a\0b" would be "a")
        link_dir = None if link_dir is None else check_path(link_dir, "link_dir")
        capture = None if capture is None else check_path(capture, "capture")
        opts = ffi.new("fap_vbus_options *")
        lib.fap_vbus_options_init(opts)
        opts.n_ports = ports
        opts.baud = baud
        opts.echo = 1 if echo else 0
        opts.seed = seed & 0xFFFFFFFFFFFFFFFF
        if realtime is not None:   # the relay thread's (docs/realtime.md)
            from .rs485 import parse_realtime
            opts.rt = parse_realtime(realtime, "realtime")[0]
        keep = []   # the C strings must outlive fap_vbus_open
        if link_dir is not None:
            keep.append(ffi.new("char[]", os.fsencode(link_dir)))
            opts.link_dir = keep[-1]
        if capture is not None:
            keep.append(ffi.new("char[]", os.fsencode(capture)))
            opts.capture_path = keep[-1]
        out = ffi.new("fap_vbus **")
        self._link_dir = link_dir
        self._link_lock = None if link_dir is None else _lock_link_dir(link_dir)
        code = lib.fap_vbus_open(out, opts)
        if code < 0:
            _unlock_link_dir(link_dir or "", self._link_lock)
            self._link_lock = None
            where = ", ".join(f"{k}={os.fsdecode(v)}" for k, v in
                              (("link_dir", link_dir), ("capture", capture)) if v is not None)
            raise error_from_code(code, f"fap_vbus_open({where})")
        self._adopt(out[0])
        self.baud = baud
        self.echo = bool(echo)
        self.paths: List[str] = [
            os.fsdecode(ffi.string(lib.fap_vbus_port_path(out[0], i))) for i in range(ports)
        ]
        log.info("virtual bus open: %d ports, baud %s, echo %s: %s",
                 ports, baud or "unpaced", self.echo, " ".join(self.paths))

    # -- lifetime (NativeHandle) -------------------------------------------
    def _release(self, bus: Any) -> None:
        lib.fap_vbus_close(bus)
        if self._link_dir is not None:
            _unlock_link_dir(self._link_dir, self._link_lock)
            self._link_lock = None
        log.info("virtual bus closed")

    def close(self) -> None:
        """Stop the relay, close the ptys, remove the symlinks. Idempotent."""
        super().close()

    def _port(self, port: int) -> int:
        return check_int(port, "port", 0, len(self.paths) - 1)

    # -- faults -----------------------------------------------------------
    def set_fault(self, port: Optional[int] = None, bit_error_rate: float = 0.0,
                  drop_rate: float = 0.0) -> None:
        """Random faults on bytes sent by ``port`` (``None``: every port).

        Each byte gets one random bit flipped with probability
        ``bit_error_rate`` and vanishes with probability ``drop_rate``.
        0 disables.
        """
        p = -1 if port is None else self._port(port)
        ber = check_probability(bit_error_rate, "bit_error_rate")
        drop = check_probability(drop_rate, "drop_rate")
        with self._lock:
            _check(self._call(lib.fap_vbus_set_fault, p, ber, drop), "set_fault")

    def _count(self, n: int) -> int:
        return check_int(n, "n", 0, _MAX_COUNT)

    def drop_next(self, port: int, n: int) -> None:
        """Drop the next ``n`` bytes sent by ``port`` (0 cancels)."""
        p, n = self._port(port), self._count(n)
        with self._lock:
            _check(self._call(lib.fap_vbus_drop_next, p, n), "drop_next")

    def corrupt_next(self, port: int, n: int) -> None:
        """Flip one (seeded random) bit in each of the next ``n`` bytes sent by ``port``."""
        p, n = self._port(port), self._count(n)
        with self._lock:
            _check(self._call(lib.fap_vbus_corrupt_next, p, n), "corrupt_next")

    def silence(self, port: int, seconds: float) -> None:
        """``port`` goes silent for ``seconds``: its bytes are dropped and it hears nothing."""
        p, ms = self._port(port), _to_ms(seconds, "silence")
        with self._lock:
            _check(self._call(lib.fap_vbus_silence, p, ms), "silence")

    def disconnect(self, port: int, seconds: float) -> None:
        """``port`` disconnects for ``seconds``.

        On return the node's open fd is hung up (reads/writes fail with EIO);
        opening the path fails (ENOENT) until the port comes back at the same
        path with a new pty.
        """
        p, ms = self._port(port), _to_ms(seconds, "disconnect")
        with self._lock:
            _check(self._call(lib.fap_vbus_disconnect, p, ms), "disconnect")

    @property
    def stats(self) -> VirtualBusStats:
        """A snapshot of the bus counters (:class:`~fap_py._stats.Counters`)."""
        st = ffi.new("fap_vbus_stats *")
        self._call(lib.fap_vbus_get_stats, st)
        return stats_from_c(VirtualBusStats, st)

    def __repr__(self) -> str:
        state = "closed" if self.closed else f"{len(self.paths)} ports"
        return f"<VirtualBus {state} baud={self.baud or 'unpaced'} echo={self.echo}>"


# -- capture files ---------------------------------------------------------

class CaptureFormatError(InvalidValueError):
    """A capture file line does not follow the documented format."""


@dataclass(frozen=True)
class CaptureRecord:
    """Bytes one port put on the wire (one data line)."""

    t_us: int     #: wire start of data[0], microseconds since the bus opened
    port: int     #: the sender
    data: bytes   #: what the receivers got (after faults and collisions)


@dataclass(frozen=True)
class CaptureEvent:
    """An event line (``# <kind> t=<t_us> key=value ...``)."""

    kind: str
    t_us: int
    fields: Dict[str, str] = field(default_factory=dict)


@dataclass
class Capture:
    """A parsed capture file."""

    header: Dict[str, str] = field(default_factory=dict)
    records: List[CaptureRecord] = field(default_factory=list)
    events: List[CaptureEvent] = field(default_factory=list)

    def data_from(self, port: int) -> bytes:
        """Everything ``port`` put on the wire, in order."""
        return b"".join(r.data for r in self.records if r.port == port)

    def events_of(self, kind: str) -> List[CaptureEvent]:
        """The events of one kind (``collision``, ``fault``, ``overflow`` ...)."""
        return [e for e in self.events if e.kind == kind]


def _fields(tokens: Iterable[str], lineno: int) -> Dict[str, str]:
    out = {}
    for tok in tokens:
        key, sep, value = tok.partition("=")
        if not sep or not key:
            raise CaptureFormatError(f"line {lineno}: expected key=value, got {tok!r}")
        out[key] = value
    return out


#: the longest capture line a reader takes (fap bus writes at most ~230 characters)
CAPTURE_LINE_MAX = 65536

CaptureItem = Union[Dict[str, str], CaptureRecord, CaptureEvent]


#: the header's fields a bus writes: each value's range (a field not given is not
#: checked; one this list lacks is kept as written, for later formats)
_HEADER_RANGES = {"ports": (2, MAX_PORTS), "baud": (0, 0xFFFFFFFF), "echo": (0, 1),
                  "seed": (0, 2**64 - 1)}


def _header(tokens: Iterable[str], lineno: int) -> Dict[str, str]:
    """The header's fields, each known one a decimal number in its range."""
    fields = _fields(tokens, lineno)
    for key, (lo, hi) in _HEADER_RANGES.items():
        value = fields.get(key)
        if value is None:
            continue
        ok = value.isascii() and value.isdigit() and len(value) <= 20 and lo <= int(value) <= hi
        if not ok:
            raise CaptureFormatError(f"line {lineno}: header {key}={value[:40]} is not a number "
                                     f"in {lo}..{hi}")
    return fields


def iter_capture(lines: Iterable[str]) -> Iterator[CaptureItem]:
    """Parse capture lines one by one (sans I/O): yields the header (a dict),
    each :class:`CaptureRecord` and :class:`CaptureEvent` in file order.

    The header's ``ports``, ``baud``, ``echo`` and ``seed`` must be numbers in
    their ranges, there is at most one header, and a data line's port must be
    below the header's ``ports``: else :class:`CaptureFormatError`."""
    if isinstance(lines, (str, bytes)) or not isinstance(lines, Iterable):
        raise InvalidTypeError(f"lines must be an iterable of str, not {type(lines).__name__}")
    n_ports: Optional[int] = None
    seen_header = False
    for lineno, raw in enumerate(lines, 1):
        if not isinstance(raw, str):
            raise InvalidTypeError(f"line {lineno}: expected str, not {type(raw).__name__}")
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            tokens = line[1:].split()
            if not tokens:
                continue
            kind = tokens[0]
            if kind == "fap-vbus-capture":
                if len(tokens) < 2 or tokens[1] != "1":
                    raise CaptureFormatError(f"line {lineno}: unsupported capture version")
                if seen_header:
                    raise CaptureFormatError(f"line {lineno}: a second capture header")
                seen_header = True
                header = _header(tokens[2:], lineno)
                if "ports" in header:
                    n_ports = int(header["ports"])
                yield header
                continue
            f = _fields(tokens[1:], lineno)
            try:
                t_us = int(f.pop("t"))
            except (KeyError, ValueError) as exc:
                raise CaptureFormatError(f"line {lineno}: event without t=<us>") from exc
            yield CaptureEvent(kind, t_us, f)
            continue
        parts = line.split()
        try:
            t_us, port = int(parts[0]), int(parts[1])
            data = bytes(int(h, 16) for h in parts[2:])
        except (IndexError, ValueError) as exc:
            raise CaptureFormatError(f"line {lineno}: bad data line {line[:80]!r}") from exc
        if not parts[2:] or any(len(h) != 2 for h in parts[2:]) or t_us < 0 or port < 0:
            raise CaptureFormatError(f"line {lineno}: bad data line {line[:80]!r}")
        if n_ports is not None and port >= n_ports:
            raise CaptureFormatError(f"line {lineno}: data from port {port}, but the header "
                                     f"says ports={n_ports}")
        yield CaptureRecord(t_us, port, data)


def parse_capture(lines: Iterable[str]) -> Capture:
    """Parse capture lines (sans I/O; see :func:`read_capture`)."""
    return _collect(iter_capture(lines))


def _collect(items: Iterable[CaptureItem]) -> Capture:
    cap = Capture()
    for item in items:
        if isinstance(item, CaptureRecord):
            cap.records.append(item)
        elif isinstance(item, CaptureEvent):
            cap.events.append(item)
        else:
            cap.header = item
    return cap


#: the largest capture file :func:`read_capture` reads (a capture is text: ~3 bytes per
#: wire byte, so this is an hour of a saturated 115200-baud bus)
MAX_CAPTURE_BYTES = 256 << 20


def capture_lines(path: PathLike, max_size: Optional[int] = None) -> Iterator[str]:
    """The lines of a capture file, streamed with bounds: a regular file only (of at
    most ``max_size`` bytes if given), ASCII lines of at most CAPTURE_LINE_MAX
    characters. Errors name the file: FileError (missing, unreadable, not a regular
    file, too large), CaptureFormatError (not a capture)."""
    limit = max_size if max_size is not None else (1 << 62)
    p, fh = open_user_file(path, limit=limit, what="capture file")
    with fh:
        lineno = 0
        while True:
            lineno += 1
            try:
                line = fh.readline(CAPTURE_LINE_MAX + 1)
            except OSError as exc:
                raise FileError(exc.errno or errno.EIO, f"capture file: {exc.strerror}", p) from None
            if not line:
                return
            if len(line) > CAPTURE_LINE_MAX:
                raise CaptureFormatError(
                    f"{p}: line {lineno}: longer than {CAPTURE_LINE_MAX} characters")
            try:
                yield line.decode("ascii")
            except UnicodeDecodeError:
                raise CaptureFormatError(f"{p}: line {lineno}: not an ASCII capture file") from None


def iter_capture_file(path: PathLike, max_size: Optional[int] = None) -> Iterator[CaptureItem]:
    """:func:`iter_capture` over :func:`capture_lines`; format errors name the file."""
    lines = capture_lines(path, max_size)
    try:
        yield from iter_capture(lines)
    except CaptureFormatError as exc:
        text = str(exc)
        p = os.fsdecode(path) if isinstance(path, (str, bytes, os.PathLike)) else str(path)
        raise CaptureFormatError(text if text.startswith(f"{p}: ") else f"{p}: {text}") from None


def read_capture(path: PathLike) -> Capture:
    """Read a capture file written by ``VirtualBus(capture=...)`` / ``fap bus --capture``.

    Raises :class:`~fap_py.errors.FileError` for a missing or unreadable file, one
    that is not a regular file (``/dev/zero``, a directory) or one larger than
    :data:`MAX_CAPTURE_BYTES`; :class:`CaptureFormatError` for bad content.
    """
    return _collect(iter_capture_file(path, MAX_CAPTURE_BYTES))

