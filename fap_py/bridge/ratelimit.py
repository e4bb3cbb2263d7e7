"""What the broker can make the bridge do, bounded: :class:`Coalescer` runs an action at
most once per interval; requests within the interval are coalesced into one run at its
end. Home Assistant's ``online`` messages (every discovery configuration again) and
Sparkplug rebirth commands (every birth again) go through one each (docs/bridge.md)."""
from __future__ import annotations

import logging
import threading
import time
from typing import Callable, Optional

from .._validate import check_seconds
from ..errors import InvalidTypeError

log = logging.getLogger(__name__)


class Coalescer:
    """``request()`` runs ``action`` now if it has not run for ``interval`` seconds, else
    once at the end of the interval, however many requests came meanwhile."""

    def __init__(self, action: Callable[[], None], interval: float, what: str) -> None:
        if not callable(action) or not isinstance(what, str):
            raise InvalidTypeError("Coalescer(action: callable, interval: float, what: str)")
        self._action = action
        self.interval = check_seconds(interval, "interval")
        self.what = what
        self._lock = threading.Lock()
        self._next = 0.0                           # monotonic time the action may run again
        self._timer: Optional[threading.Timer] = None
        self._closed = False
        self.requests = 0      #: requests received
        self.runs = 0          #: times the action ran
        self.coalesced = 0     #: requests folded into another run

    def request(self) -> None:
        with self._lock:
            if self._closed:
                return
            self.requests += 1
            now = time.monotonic()
            if now >= self._next and self._timer is None:
                self._next = now + self.interval
                run = True
            else:
                run = False
                self.coalesced += 1
                if self._timer is None:
                    self._timer = threading.Timer(max(0.0, self._next - now), self._fire)
                    self._timer.daemon = True
                    self._timer.name = f"fap-bridge-{self.what}"
                    self._timer.start()
                    log.info("%s requested again within %g s: coalesced into one at the end of it",
                             self.what, self.interval)
        if run:
            self._run()

    def _fire(self) -> None:
        with self._lock:
            self._timer = None
            if self._closed:
                return
            self._next = time.monotonic() + self.interval
        self._run()

    def _run(self) -> None:
        self.runs += 1
        try:
            self._action()
        except Exception:   # a timer thread or paho's: never let it die of the action
            log.exception("%s", self.what)

    def close(self) -> None:
        """No more runs (a pending one is cancelled)."""
        with self._lock:
            self._closed = True
            timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()


__all__ = ["Coalescer"]
