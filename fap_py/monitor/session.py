"""One monitor session: a source, a decoder, the outputs and the statistics.

Both front ends run the monitor through here: ``fap monitor``
(:mod:`fap_py.commands.monitor` keeps only its arguments and exit codes) and
the Wireshark extcap (:mod:`fap_py.monitor.extcap`)::

    cfg = SessionConfig(protocol="exec", device="/dev/ttyUSB0", baud=115200, idle_s=None)
    ended_by = Session(cfg).run()      # 0: input read to its end, else the signal

SIGTERM (Wireshark's stop) and SIGINT end every input within a read (at most
``sources.POLL_S`` on a quiet pipe, 200 ms on a quiet port) with the summary.
The handler only sets a flag, so no KeyboardInterrupt lands inside a cffi
callback; it is installed (main thread only) before the input opens. A write
still blocked :data:`STUCK_S` after a signal (a reader that stopped reading)
is abandoned: the rest of the output is dropped and the summary goes to stderr.
"""
from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
from dataclasses import dataclass
from types import FrameType
from typing import IO, Any, Dict, Iterator, List, Optional, Tuple

from .. import _protocols
from .._validate import U32, check_bool, check_int, check_path, check_seconds
from ..errors import InvalidTypeError, InvalidValueError
from ..rs485 import DEFAULT_BAUD, RS485
from .core import Monitor, Record
from .output import human_line, json_line
from .pcap import PcapWriter
from .sources import Chunk, LivePort, capture_file, raw_file, stream
from .stats import Stats, StatsSnapshot

log = logging.getLogger(__name__)

#: the protocol choice that tries every decoder until one locks on
AUTO = "auto"
#: a live port's rate when none is given: the port layer's default (from C)
LIVE_BAUD = DEFAULT_BAUD
#: how long a write may still block after a signal before the output is abandoned, s
STUCK_S = 0.2


def protocol_choices() -> Tuple[str, ...]:
    """What ``--protocol`` takes: ``auto`` and every protocol's one name (the table's)."""
    return (AUTO,) + _protocols.names()


def protocol_choice(protocol: Any) -> str:
    """``auto`` or the one name of ``protocol`` (an alias such as ``execasync``
    included); UnknownProtocolError (an InvalidValueError) otherwise."""
    if isinstance(protocol, str) and protocol.strip().lower() == AUTO:
        return AUTO
    if not isinstance(protocol, str):
        raise InvalidTypeError(f"protocol must be a str, not {type(protocol).__name__}")
    try:
        return _protocols.get(protocol).name
    except _protocols.UnknownProtocolError:
        raise _protocols.UnknownProtocolError(
            f"unknown protocol {protocol!r} (choose from {', '.join(protocol_choices())})") from None


def _opt_path(value: Any, what: str) -> Optional[str]:
    return None if value is None else check_path(value, what)


@dataclass(frozen=True)
class SessionConfig:
    """What a session reads, how it decodes, where it writes.

    One input at most: ``device`` (a live serial port, opened receive-only),
    ``raw_file`` (bytes as recorded), ``capture_file`` (a virtual-bus capture);
    none of them: stdin. ``baud`` 0: the live port opens at :data:`LIVE_BAUD`,
    other inputs take their own rate (a capture's header) or none.
    ``idle_s``: a live port stops after this much silence (None: only a signal
    stops it). ``stats_only`` writes only the summary; ``pcap_file`` also gets
    every record. Bad values raise InvalidTypeError / InvalidValueError.
    """

    protocol: str = AUTO
    device: Optional[str] = None
    raw_file: Optional[str] = None
    capture_file: Optional[str] = None
    baud: int = 0
    rs485: Optional[RS485] = None
    idle_s: Optional[float] = 2.0
    as_json: bool = False
    stats_only: bool = False
    pcap_file: Optional[str] = None
    quiet: bool = False

    def __post_init__(self) -> None:
        fix = object.__setattr__           # normalised values of a frozen dataclass
        fix(self, "protocol", protocol_choice(self.protocol))
        for name in ("device", "raw_file", "capture_file", "pcap_file"):
            fix(self, name, _opt_path(getattr(self, name), name))
        given = [n for n in ("device", "raw_file", "capture_file") if getattr(self, n)]
        if len(given) > 1:
            raise InvalidValueError(f"one input, not {' and '.join(given)}")
        check_int(self.baud, "baud", 0, U32)
        if self.rs485 is not None and not isinstance(self.rs485, RS485):
            raise InvalidTypeError(f"rs485 must be None or an RS485, not {type(self.rs485).__name__}")
        if self.idle_s is not None:
            fix(self, "idle_s", check_seconds(self.idle_s, "idle_s"))
        for name in ("as_json", "stats_only", "quiet"):
            check_bool(getattr(self, name), name)


class _OutputStuck(Exception):
    """A signal came while a write to the output or the pcap blocked (nobody reads)."""


class Session:
    """One run of the monitor over the input of a :class:`SessionConfig`.

    ``out``: where records and the summary go (a text stream; None: stdout).
    :meth:`run` once; :attr:`stats` and :attr:`protocol` tell the outcome.
    """

    def __init__(self, config: SessionConfig, out: Optional[IO[str]] = None) -> None:
        if not isinstance(config, SessionConfig):
            raise InvalidTypeError(f"config must be a SessionConfig, not {type(config).__name__}")
        if out is not None and not callable(getattr(out, "write", None)):
            raise InvalidTypeError(f"out must be a text stream, not {type(out).__name__}")
        self.config = config
        self._out = out
        self._stats = Stats(config.baud)
        self._monitor: Optional[Monitor] = None
        self._stopped: List[int] = []      # the signals received
        self._writing = False              # an output write is under way (it may block)
        self._timed = False                # our handlers are installed (main thread): a timer may end a write

    @property
    def stats(self) -> StatsSnapshot:
        """The bus statistics so far (a frozen snapshot)."""
        return self._stats.snapshot

    @property
    def protocol(self) -> Optional[str]:
        """The protocol decoded (``auto``: the one it locked on; None before that)."""
        return None if self._monitor is None else self._monitor.locked

    # -- signals --------------------------------------------------------------
    def _on_signal(self, signum: int, frame: Optional[FrameType]) -> None:
        self._stopped.append(signum)
        if self._writing:                  # a write still blocked STUCK_S later is abandoned
            signal.setitimer(signal.ITIMER_REAL, STUCK_S)

    def _on_alarm(self, signum: int, frame: Optional[FrameType]) -> None:
        if self._writing:
            self._writing = False
            raise _OutputStuck()

    def _begin_write(self) -> None:
        """An output write starts. After a signal it may not block for good: a reader
        that stopped reading gets STUCK_S, then the write is abandoned (_OutputStuck)."""
        self._writing = True
        if self._stopped and self._timed:
            signal.setitimer(signal.ITIMER_REAL, STUCK_S)

    def run(self) -> int:
        """Read the input to its end (or a signal); 0, or the signal that ended it
        (``signal.SIGINT`` / ``SIGTERM``). Open errors raise (PortError, FileError,
        CaptureFormatError ...) before anything is written."""
        old: Dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():   # Python's rule for handlers
            old = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
            old[signal.SIGALRM] = signal.signal(signal.SIGALRM, self._on_alarm)
            self._timed = True
        try:
            self._run()
        finally:
            if old:
                signal.setitimer(signal.ITIMER_REAL, 0)
            for sig, handler in old.items():
                signal.signal(sig, handler)
        if signal.SIGINT in self._stopped:
            return int(signal.SIGINT)
        return int(self._stopped[0]) if self._stopped else 0

    def _stop(self) -> bool:
        return bool(self._stopped)

    def _open(self) -> Tuple[Optional[LivePort], Optional[IO[bytes]], Iterator[Chunk], int]:
        """(the live port or None, the raw file or None, the other input's chunks, the rate)."""
        cfg = self.config
        if cfg.device:
            live = LivePort(cfg.device, cfg.baud or LIVE_BAUD, cfg.rs485)
            # tells a person (and a test) that bytes from now on are seen
            self._status(f"listening on {cfg.device} at {live.baud} baud", flush=True)
            return live, None, iter(()), live.baud
        if cfg.raw_file:
            fh = open(cfg.raw_file, "rb")
            return None, fh, raw_file(fh, self._stop), cfg.baud
        if cfg.capture_file:
            cap_baud, chunks = capture_file(cfg.capture_file, self._stop)
            return None, None, chunks, cfg.baud or cap_baud
        return None, None, stream(sys.stdin.fileno(), cfg.baud, self._stop), cfg.baud

    def _status(self, text: str, flush: bool = False) -> None:
        if not self.config.quiet:          # Wireshark's extcap takes any stderr text for an error
            print(f"fap monitor: {text}", file=sys.stderr, flush=flush)

    def _run(self) -> None:
        cfg = self.config
        live, fh, chunks, baud = self._open()
        try:
            # after the input: an extcap fifo's reader sees the header once the port is open
            pcap = PcapWriter(open(cfg.pcap_file, "wb")) if cfg.pcap_file else None
        except BaseException:
            for opened in (live, fh):
                if opened is not None:
                    opened.close()
            raise
        self._stats = Stats(baud)
        mon = self._monitor = Monitor(cfg.protocol, baud)
        writer = _Writer(self, mon, pcap, live is not None)
        out = self._out or sys.stdout
        stuck = False
        try:
            if live is not None:
                with live:
                    for chunk in live.chunks(mon.idle_deadline, cfg.idle_s, self._stop):
                        if chunk is None:
                            writer.emit(out, mon.idle(live.now_ns()))
                        else:
                            writer.emit(out, mon.feed(chunk.data, chunk.t, chunk.char_s,
                                                      chunk.port, chunk.now_ns))
            else:
                for chunk in chunks:
                    writer.emit(out, mon.feed(chunk.data, chunk.t, chunk.char_s, chunk.port,
                                              chunk.now_ns))
                    if self._stopped:
                        break
            writer.emit(out, mon.finish())
        except _OutputStuck:
            # nobody reads the output (or the pcap fifo): drop what is still buffered there
            stuck = True
            _drop_output(out, pcap)
            pcap = None
        finally:
            if fh is not None:
                fh.close()
            if pcap:
                pcap.close()
                pcap._fh.close()
        self._stats.bytes = mon.bytes
        if not stuck:
            try:
                self._begin_write()
                self._summary(out, writer)
                return
            except _OutputStuck:         # a signal, then a reader that stopped reading
                _drop_output(out, None)
            finally:
                self._writing = False
        if not cfg.quiet:
            self._summary(sys.stderr, writer)

    def _summary(self, out: IO[str], writer: "_Writer") -> None:
        cfg, mon = self.config, self._monitor
        writer.announce()
        if cfg.as_json and cfg.stats_only:
            summary = self._stats.summary()
            summary["protocol"] = None if mon is None else mon.locked
            out.write(json.dumps({"event": "stats", "stats": summary}) + "\n")
        elif not cfg.as_json:
            out.write(self._stats.footer() + "\n")
        out.flush()


class _Writer:
    """The records' way out: statistics, pcap, text or JSON lines, auto's announcement."""

    def __init__(self, session: Session, mon: Monitor, pcap: Optional[PcapWriter],
                 live: bool) -> None:
        cfg = session.config
        self.session, self.mon, self.pcap = session, mon, pcap
        # a live port or a pipe: each read's records are on the output before the next read
        self.flush = live or not (cfg.raw_file or cfg.capture_file)
        # wall-clock times (live port, stdin) are shown from the first record on
        self.relative = cfg.capture_file is None and cfg.raw_file is None
        self.t0: Optional[float] = None
        self.announced = mon.locked is not None

    def announce(self) -> None:
        mon = self.mon
        if self.announced or not mon.locked:
            return
        self.announced = True
        if mon.lock_frames:
            good = f"{mon.lock_frames} good frame{'' if mon.lock_frames == 1 else 's'}"
            self.session._status(f"auto: locked on {mon.locked} ({good})")
        else:
            self.session._status(f"auto: no protocol recognised (no good frame in {mon.bytes} "
                                 f"bytes); showing the bytes as {mon.locked}")

    def emit(self, out: IO[str], recs: List[Record]) -> None:
        session, cfg, pcap = self.session, self.session.config, self.pcap
        self.announce()
        session._begin_write()
        try:
            for rec in recs:
                session._stats.add(rec)
                if pcap:
                    pcap.write(rec)
                if cfg.stats_only:
                    continue
                if cfg.as_json:
                    out.write(json_line(rec) + "\n")
                else:
                    if self.t0 is None and rec.t is not None and self.relative:
                        self.t0 = rec.t
                    out.write(human_line(rec, self.t0) + "\n")
            if self.flush and recs:
                out.flush()
                if pcap:
                    pcap.flush()
        finally:
            session._writing = False


def _drop_output(out: IO[str], pcap: Optional[PcapWriter]) -> None:
    """Point the output and the pcap at /dev/null: their buffered bytes can never be written."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fh in (out, pcap._fh if pcap else None):
            try:
                if fh is not None:
                    os.dup2(devnull, fh.fileno())
            except (OSError, ValueError, AttributeError):
                pass
    finally:
        os.close(devnull)


__all__ = ["AUTO", "LIVE_BAUD", "STUCK_S", "Session", "SessionConfig", "protocol_choice",
           "protocol_choices"]
