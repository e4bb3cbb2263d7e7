"""Progress bars on stderr (rich) for long runs: ``fap`` scans and soaks,
``python -m bench``. Silent when stderr is not a terminal, so piped and
logged output stays clean."""
from __future__ import annotations

import contextlib
import math
import sys
import threading
import time
from typing import Any, ContextManager, Iterator, Optional

from ._validate import check_bool, check_seconds
from .errors import InvalidTypeError, InvalidValueError

__all__ = ["Progress", "timed_progress"]

#: the most steps a bar counts (more is a mistake, not a run)
MAX_STEPS = 1 << 53
#: the longest label shown
MAX_LABEL = 200


def _count(value: Any, what: str) -> float:
    """A finite number of steps in 0..MAX_STEPS (not a bool)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidTypeError(f"{what} must be a number of steps, not {type(value).__name__}")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf
    if not 0.0 <= v <= MAX_STEPS:     # NaN fails both
        raise InvalidValueError(f"{what} must be a finite number of steps in 0..{MAX_STEPS}, not {value}")
    return v


def _label(value: Any, what: str = "label") -> str:
    if not isinstance(value, str):
        raise InvalidTypeError(f"{what} must be a str, not {type(value).__name__}")
    if "\0" in value or len(value) > MAX_LABEL:
        raise InvalidValueError(f"{what} must be at most {MAX_LABEL} characters without NUL, "
                                f"not {value[:40]!r}...")
    return value


class Progress:
    """A progress bar on stderr (rich) when ``enabled`` and stderr is a
    terminal; silent otherwise. Lines printed on a terminal stdout go above
    the bar (rich's live display); a redirected stdout keeps them."""

    def __init__(self, total: float, label: str, enabled: bool = True) -> None:
        total = _count(total, "total")
        label = _label(label)
        check_bool(enabled, "enabled")
        self._bar: Any = None
        self._task: Any = None
        if enabled and sys.stderr.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
            from rich.progress import Progress as RichProgress

            self._bar = RichProgress(TextColumn("{task.description}"), BarColumn(),
                                     MofNCompleteColumn(), TimeRemainingColumn(),
                                     console=Console(stderr=True), transient=True,
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
        """One more step done (``description``: what runs now)."""
        if description is not None:
            _label(description, "description")
        if self._bar is not None:
            self._bar.update(self._task, advance=1,
                             **({"description": description} if description else {}))

    def set(self, completed: float) -> None:
        """``completed`` steps done (a finite number >= 0)."""
        completed = _count(completed, "completed")
        if self._bar is not None:
            self._bar.update(self._task, completed=completed)


def timed_progress(label: str, seconds: float, enabled: bool = True) -> ContextManager[None]:
    """A bar that fills with the wall clock over ``seconds`` (a soak runs
    for a set time) while the block runs; nothing without a terminal.
    The arguments are checked at the call, before the ``with`` block
    (``seconds``: a finite number >= 0, as every duration of the package)."""
    label = _label(label)
    seconds = check_seconds(seconds, "seconds")
    check_bool(enabled, "enabled")
    return _timed(label, seconds, enabled)


@contextlib.contextmanager
def _timed(label: str, seconds: float, enabled: bool) -> Iterator[None]:
    bar = Progress(round(seconds), label, enabled)
    if bar._bar is None:
        yield
        return
    stop = threading.Event()
    t0 = time.monotonic()

    def tick() -> None:
        while not stop.wait(0.25):
            bar.set(min(seconds, time.monotonic() - t0))

    ticker = threading.Thread(target=tick, daemon=True)
    with bar:
        ticker.start()
        try:
            yield
        finally:
            stop.set()
            ticker.join()


