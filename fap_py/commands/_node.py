"""What the node commands (``fap fap|exec|mikroc master|slave``, ``fap g485``)
share: payloads from arguments or stdin, the ``--count``/``--interval``
loop, readiness lines, progress bars for scans."""
from __future__ import annotations

import argparse
import contextlib
import os
import select
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterator, List, Optional, Union

from ..errors import InvalidValueError
from ..progress import Progress, timed_progress  # noqa: F401  (the commands' bars)
from ._options import EXIT_INTERRUPTED, BusError, UsageError, emit, hexbytes


def add_payload_options(parser: argparse.ArgumentParser, *, what: str = "payload",
                        size: str = "") -> None:
    """``DATA...`` (hex, or text with ``--text``); ``-`` reads one payload
    per stdin line, each sent as it arrives."""
    parser.add_argument("data", nargs="*", metavar="DATA",
                        help=f"{what}s{size} to send, hex (e.g. 0102 or '01 02'); '-' reads one "
                        "per line from stdin, each sent as it arrives")
    parser.add_argument("--text", action="store_true",
                        help="DATA and stdin lines are text (UTF-8), not hex")


def reply_option(max_len: Optional[int] = None) -> Callable[[str], str]:
    """argparse type of a slave's ``--reply``: ``echo``, ``none`` or hex bytes
    (at most ``max_len``), checked at parse time so a bad value is a usage
    error naming ``--reply``."""
    def check(text: str) -> str:
        if text not in ("echo", "none"):
            data = hexbytes(text)          # ArgumentTypeError: "not hex bytes: 'zz'"
            if max_len is not None and len(data) > max_len:
                raise argparse.ArgumentTypeError(
                    f"a reply is 0..{max_len} bytes, not {len(data)}: {text!r}")
        return text
    return check


def note(args: argparse.Namespace, obj: Dict[str, Any], text: str) -> None:
    """A problem that does not end the command: a JSON line on stdout with
    ``--json``, else ``fap: TEXT`` on stderr."""
    if getattr(args, "json", False):
        emit(args, obj, None)
    else:
        sys.stderr.write(f"fap: {text}\n")
        sys.stderr.flush()


#: longest stdin line kept (bytes): far over any payload of the four
#: protocols in hex; a longer one is a bad line, not a growing buffer
MAX_LINE = 1 << 16


class Payloads:
    """The DATA of a node command, one pass per ``--count`` repetition.

    Arguments are checked at once (a bad one is a usage error). A ``-`` is
    stdin, read line by line in the first pass, each payload yielded as its
    line arrives (so ``tail -f | fap ... -`` works); a line that is not a
    payload is reported by :func:`note`, counted in :attr:`bad`, and
    skipped. Later passes replay the stdin payloads read. No DATA at all is
    one empty payload per pass (``empty``).
    """

    def __init__(self, args: argparse.Namespace, *, empty: bool = True,
                 check: Optional[Callable[[bytes], Any]] = None) -> None:
        self.args = args
        #: the protocol's own check of one payload (its size, say): an
        #: InvalidValueError makes it a bad payload (argument: exit 2; stdin
        #: line: reported and skipped), never the end of a stdin batch
        self.check = check
        self.stop: Optional[threading.Event] = None   #: ends a stdin wait when set
        #: called while a stdin wait (with :attr:`stop` set) has nothing to read,
        #: every 0.2 s: a command keeps its own work going between lines
        self.idle: Optional[Callable[[], None]] = None
        self.bad = 0                      #: stdin lines that were not payloads
        self.lines = 0                    #: stdin lines read (blank ones not counted)
        self._stdin: List[bytes] = []
        self._read = False
        self._items: List[Optional[bytes]] = []   # None: where stdin goes
        for item in args.data:
            self._items.append(None if item == "-" else self._parse(item))
        if not self._items and empty:
            self._items.append(b"")

    def _parse(self, item: Union[str, bytes]) -> bytes:
        if isinstance(item, bytes):
            if self.args.text:
                return self._checked(item)
            item = item.decode("ascii", errors="backslashreplace")
        if self.args.text:
            return self._checked(item.encode())
        try:
            data = hexbytes(item)
        except argparse.ArgumentTypeError as exc:
            raise UsageError(f"{exc} (use --text for text payloads)") from None
        return self._checked(data)

    def _checked(self, data: bytes) -> bytes:
        if self.check is not None:
            try:
                self.check(data)
            except InvalidValueError as exc:
                raise UsageError(str(exc)) from None
        return data

    def _raw_lines(self) -> Iterator[Union[str, bytes, None]]:
        """stdin line by line as each arrives (``os.read`` of what is there,
        no read-ahead); None for a line over :data:`MAX_LINE`; with
        :attr:`stop` set, also ends when it is set (a command whose SIGINT
        only sets a flag)."""
        try:
            fd = sys.stdin.fileno()
        except (AttributeError, OSError, ValueError):      # not a file (tests: StringIO)
            yield from iter(sys.stdin.readline, "")
            return
        buf = b""
        skipping = False           # inside a line over MAX_LINE: dropped up to its newline
        while True:
            if self.stop is not None:
                ready, _, _ = select.select([fd], [], [], 0.2)
                if self.stop.is_set():
                    return
                if not ready:
                    if self.idle is not None:
                        self.idle()
                    continue
            chunk = os.read(fd, 65536)
            if not chunk:
                break
            *lines, buf = (buf + chunk).split(b"\n")
            for line in lines:
                if skipping:
                    skipping = False
                else:
                    yield line
            if len(buf) > MAX_LINE:
                if not skipping:
                    yield None         # reported as a line that is not a payload
                buf, skipping = b"", True
        if buf and not skipping:
            yield buf

    def _stdin_lines(self) -> Iterator[bytes]:
        for raw in self._raw_lines():
            line: Union[str, bytes, None] = raw.rstrip(b"\r\n") if isinstance(raw, bytes) \
                else raw if raw is None else raw.rstrip("\r\n")
            if line is not None and not line.strip():
                continue
            self.lines += 1
            try:
                if line is None:
                    raise UsageError(f"longer than {MAX_LINE} bytes")
                data = self._parse(line)
            except UsageError as exc:
                self.bad += 1
                note(self.args, {"event": "bad_input", "line": self.lines, "error": str(exc)},
                     f"stdin line {self.lines}: {exc}; skipped")
                continue
            self._stdin.append(data)
            yield data
        self._read = True

    def __iter__(self) -> Iterator[bytes]:
        for item in self._items:
            if item is not None:
                yield item
            elif self._read:
                yield from self._stdin
            else:
                yield from self._stdin_lines()

    def passes(self) -> Iterator["Payloads"]:
        """This object once per ``--count`` repetition (0 = forever),
        ``--interval`` apart."""
        for _ in repetitions(self.args):
            yield self

    def finish(self, failed: str = "") -> None:
        """End of the command: :class:`UsageError` (exit 2) when stdin lines
        were skipped, else :class:`BusError` (exit 1) with ``failed`` if given."""
        if self.bad:
            raise UsageError(f"{self.bad} of {self.lines} stdin lines were not payloads "
                             f"(skipped){'; ' + failed if failed else ''}")
        if failed:
            raise BusError(failed)


def show(data: bytes) -> str:
    """Hex, plus the text when it is all printable ASCII."""
    if not data:
        return "(empty)"
    text = data.hex(" ")
    try:
        s = data.decode("ascii")
        if s and s.isprintable():
            return f'{text}  "{s}"'
    except UnicodeDecodeError:
        pass
    return text


def repetitions(args: argparse.Namespace) -> Iterator[int]:
    """0, 1, ... ``--count`` (0 = forever), sleeping ``--interval`` between."""
    i = 0
    while args.count == 0 or i < args.count:
        if i:
            time.sleep(args.interval)
        yield i
        i += 1


class Stop(threading.Event):
    """Set by SIGTERM or SIGINT; :attr:`signum` says which."""

    signum: Optional[int] = None

    @property
    def interrupted(self) -> bool:
        """True when Ctrl-C (SIGINT) ended the block: exit 130."""
        return self.signum == signal.SIGINT


@contextlib.contextmanager
def stop_on_sigterm() -> Iterator[Stop]:
    """An event set by SIGTERM (and SIGINT) while the block runs, so a
    served loop can end cleanly and print its summary."""
    done = Stop()
    if threading.current_thread() is not threading.main_thread():
        yield done
        return

    def on_signal(signum: int, _frame: Any) -> None:
        done.signum = signum
        done.set()

    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    for s in old:
        signal.signal(s, on_signal)
    try:
        yield done
    finally:
        for s, h in old.items():
            signal.signal(s, h)


class Terminated(KeyboardInterrupt):
    """SIGTERM in a client command: raised where SIGINT raises KeyboardInterrupt, so the
    command ends the same way (its summary, ``"interrupted": true``, exit 130)."""


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """While the block runs, SIGTERM raises :class:`Terminated` (a KeyboardInterrupt):
    every ``except KeyboardInterrupt`` that prints a client's summary handles it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(_signum: int, _frame: Any) -> None:
        raise Terminated()

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


#: What ends a long-running command and with which exit code (docs/cli.md):
#: a client (polling, scanning) ends on SIGINT or SIGTERM with its summary
#: (``"interrupted": true``) and exit 130; a server (slave, sim) ends on
#: either with its summary and exit 0, its normal end.
CLIENT, SERVER = "client", "server"


def long_running(parser: argparse.ArgumentParser, kind: str,
                 func: Callable[[argparse.Namespace], int]) -> None:
    """Register ``func`` as the parser's command, a long-running one of ``kind``
    (:data:`CLIENT` or :data:`SERVER`): the CLI's registry of what runs until its
    count, its scan or a signal ends it (``parser.get_default("long_running")``;
    tests/python/cli/test_signals.py walks it). A client's ``func`` runs with
    SIGTERM raising :class:`Terminated` (:func:`sigterm_interrupts`), unless it
    handles the signals itself (``handles_signals``: :func:`stop_on_sigterm`)."""
    if kind not in (CLIENT, SERVER):
        raise InvalidValueError(f"long_running: kind is {CLIENT!r} or {SERVER!r}, not {kind!r}")
    run = func
    if kind == CLIENT and not getattr(func, "handles_signals", False):
        def run(args: argparse.Namespace) -> int:
            with sigterm_interrupts():
                return func(args)
        run.__doc__, run.__name__ = func.__doc__, func.__name__
    parser.set_defaults(func=run, long_running=kind)


def handles_signals(func: Callable[..., int]) -> Callable[..., int]:
    """Mark a client command that ends on SIGINT/SIGTERM by itself (with
    :func:`stop_on_sigterm`), so :func:`long_running` leaves its signals alone."""
    func.handles_signals = True  # type: ignore[attr-defined]
    return func


@dataclass
class ScanResult:
    """What a scan found, how many ids it tried, and whether Ctrl-C cut it short."""

    found: List[int]
    tried: int
    interrupted: bool = False


def scan(ids: List[int], probe: Callable[[int], Optional[Any]], *, label: str,
         progress: bool, found: Callable[[int, Any], None]) -> ScanResult:
    """Probe every id in turn; ``found`` is called for each that answers.
    Ctrl-C or SIGTERM (a :class:`long_running` client) ends the scan early
    (``interrupted``): the caller still prints its summary."""
    result = ScanResult([], 0)
    with Progress(len(ids), label, progress) as bar:
        try:
            for i in ids:
                bar.advance(f"{label} {i}")
                answer = probe(i)
                result.tried += 1
                if answer is not None:
                    result.found.append(i)
                    found(i, answer)
        except KeyboardInterrupt:
            result.interrupted = True
    return result


def scan_summary(args: argparse.Namespace, result: ScanResult, total: int, what: str) -> int:
    """The summary line of a scan and its exit code (0 found, 1 none, 130 Ctrl-C)."""
    found, tried = result.found, result.tried
    emit(args, {"event": "summary", "found": found, "tried": tried,
                **({"interrupted": True, "of": total} if result.interrupted else {})},
         f"{len(found)} of {tried} {what} answered" + (f": {', '.join(map(str, found))}"
                                                        if found else "")
         + (f" (interrupted after {tried} of {total})" if result.interrupted else ""))
    if result.interrupted:
        return EXIT_INTERRUPTED
    return 0 if found else 1
