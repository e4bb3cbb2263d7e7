"""What the node commands (``fap fap|exec|mikroc master|slave``, ``fap g485``)
share: payloads from arguments or stdin, the ``--count``/``--interval``
loop, readiness lines, progress bars for scans."""
from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from typing import Any, Callable, Iterator, List, Optional

from ._options import UsageError, hexbytes


def add_payload_options(parser: argparse.ArgumentParser, *, what: str = "payload") -> None:
    """``DATA...`` (hex, or text with ``--text``); ``-`` reads one payload
    per stdin line."""
    parser.add_argument("data", nargs="*", metavar="DATA",
                        help=f"{what}s to send, hex (e.g. 0102 or '01 02'); '-' reads one "
                        "per line from stdin")
    parser.add_argument("--text", action="store_true",
                        help="DATA and stdin lines are text (UTF-8), not hex")


def payloads(args: argparse.Namespace, *, allow_empty: bool = True) -> List[bytes]:
    """The payloads of the command line, or of stdin."""
    items: List[str] = []
    for item in args.data:
        if item == "-":
            items.extend(line.rstrip("\r\n") for line in sys.stdin if line.strip())
        else:
            items.append(item)
    out: List[bytes] = []
    for item in items:
        if args.text:
            out.append(item.encode())
        else:
            try:
                out.append(hexbytes(item))
            except argparse.ArgumentTypeError as exc:
                raise UsageError(f"{exc} (use --text for text payloads)") from None
    if not out and not allow_empty:
        raise UsageError("nothing to send: give DATA, or '-' and payloads on stdin")
    return out


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


@contextlib.contextmanager
def stop_on_sigterm() -> Iterator[threading.Event]:
    """An event set by SIGTERM (and SIGINT) while the block runs, so a
    served loop can end cleanly and print its summary."""
    done = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield done
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    for s in old:
        signal.signal(s, lambda *_: done.set())
    try:
        yield done
    finally:
        for s, h in old.items():
            signal.signal(s, h)


class Progress:
    """A progress bar on stderr (rich) when stderr is a terminal and not
    ``--json``; silent otherwise. Found devices are printed by the caller as
    they answer (rich's live display keeps plain prints above the bar)."""

    def __init__(self, total: int, label: str, enabled: bool) -> None:
        self._bar: Any = None
        self._task: Any = None
        if enabled and sys.stderr.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
            from rich.progress import Progress as RichProgress

            self._bar = RichProgress(TextColumn("{task.description}"), BarColumn(),
                                     MofNCompleteColumn(), TimeRemainingColumn(),
                                     console=Console(stderr=True), transient=True,
                                     # lines printed on a terminal stdout go above the bar;
                                     # a redirected stdout keeps them (never into stderr)
                                     redirect_stdout=sys.stdout.isatty(), redirect_stderr=False)
            self._task = self._bar.add_task(label, total=total)

    def __enter__(self) -> "Progress":
        if self._bar is not None:
            self._bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()

    def advance(self, description: Optional[str] = None) -> None:
        if self._bar is not None:
            self._bar.update(self._task, advance=1,
                             **({"description": description} if description else {}))


def scan(ids: List[int], probe: Callable[[int], Optional[Any]], *, label: str,
         progress: bool, found: Callable[[int, Any], None]) -> List[int]:
    """Probe every id in turn; ``found`` is called for each that answers."""
    answered: List[int] = []
    with Progress(len(ids), label, progress) as bar:
        for i in ids:
            bar.advance(f"{label} {i}")
            result = probe(i)
            if result is not None:
                answered.append(i)
                found(i, result)
    return answered
