"""A progress bar on stderr (rich, a dependency of fap_py) when stderr is a
terminal; silent otherwise. The bench's own, so that it imports nothing of
the CLI's private modules (the CLI's bar, ``fap soak``'s, looks the same)."""
from __future__ import annotations

import sys
from typing import Any, Optional


class Progress:
    """``with Progress(steps, "bench") as bar: bar.advance("what runs now")``.
    Lines printed on a terminal stdout go above the bar; a redirected stdout
    keeps them."""

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
