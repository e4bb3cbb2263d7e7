"""Progress bars on stderr (rich) for long runs: ``fap`` scans and soaks,
``python -m bench``. Silent when stderr is not a terminal, so piped and
logged output stays clean."""
from __future__ import annotations

import contextlib
import sys
import threading
import time
from typing import Any, Iterator, Optional

__all__ = ["Progress", "timed_progress"]


class Progress:
    """A progress bar on stderr (rich) when ``enabled`` and stderr is a
    terminal; silent otherwise. Lines printed on a terminal stdout go above
    the bar (rich's live display); a redirected stdout keeps them."""

    def __init__(self, total: float, label: str, enabled: bool = True) -> None:
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
        if self._bar is not None:
            self._bar.update(self._task, advance=1,
                             **({"description": description} if description else {}))

    def set(self, completed: float) -> None:
        if self._bar is not None:
            self._bar.update(self._task, completed=completed)


@contextlib.contextmanager
def timed_progress(label: str, seconds: float, enabled: bool = True) -> Iterator[None]:
    """A bar that fills with the wall clock over ``seconds`` (a soak runs
    for a set time) while the block runs; nothing without a terminal."""
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


