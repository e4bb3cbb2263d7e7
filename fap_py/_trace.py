"""Wire bytes of every frame on the ``fap_py.wire.*`` loggers, at DEBUG.

The C core calls a trace hook (``fap_trace.h``) with the raw bytes of every
frame a handle sends or receives, good or bad. This module installs one
cffi ``extern "Python"`` hook, :func:`fap_py_trace`, on a handle **only when
its logger is enabled for DEBUG at the moment the node opens** (``fap -vv``,
or ``logging.getLogger("fap_py.wire").setLevel(logging.DEBUG)`` first). A
node opened without it pays nothing: no hook, no GIL taken per frame.

Loggers: ``fap_py.wire.fap`` (FAP handles), ``fap_py.wire.exec`` (exec async
master and slave), ``fap_py.wire.mikroc`` (mikroC contexts). Each record
reads ``<port> rx|tx <status> <n> bytes: <hex>`` and carries ``extra``
fields ``wire_dir``, ``wire_status``, ``wire_t_ns`` (CLOCK_MONOTONIC),
``wire_bytes`` for handlers that want the data, not the text.

The hook runs on the thread that moved the bytes (for FAP the engine's C
thread, which takes the GIL for the call); logging is thread-safe. Keep
handlers on these loggers quick: a slow one slows the engine.

Ctrl-C: for exec async and mikroC the hook runs on the main thread, inside a
C call. A ``KeyboardInterrupt`` raised there could not cross into C (cffi
prints it and drops it, and the program went on). So while a hook is
installed, SIGINT's Python handler is wrapped (:func:`_guard_sigint`, main
thread only): a Ctrl-C that lands inside the hook is marked deferred
(:class:`fap_py._handle.DeferredSigint`); the handle wrapper that made the C
call puts it back as pending when that call returns, and the handler raises it
in the Python code that made the call. No thread, no polling.
"""
from __future__ import annotations

import logging
import signal
import threading
from types import FrameType
from typing import Any, Callable, Optional

from ._handle import DeferredSigint
from ._native import ffi, lib

_DIRS = {lib.FAP_TRACE_RX: "rx", lib.FAP_TRACE_TX: "tx"}
_STATUS = {lib.FAP_TRACE_OK: "ok", lib.FAP_TRACE_BAD_CRC: "bad_crc",
           lib.FAP_TRACE_BAD_FRAME: "bad_frame", lib.FAP_TRACE_TRUNCATED: "truncated",
           lib.FAP_TRACE_TX_FAILED: "tx_failed"}


def wire_logger(protocol: str) -> logging.Logger:
    """``fap_py.wire.<protocol>``."""
    return logging.getLogger(f"fap_py.wire.{protocol}")


class Tap:
    """What the hook needs to log one handle's frames; keep it alive as long
    as the handle (it owns the cffi handle passed to C as ``ctx``)."""

    def __init__(self, logger: logging.Logger, label: str) -> None:
        self.logger = logger
        self.label = label
        self.handle = ffi.new_handle(self)

    def log(self, f: Any) -> None:
        data = bytes(ffi.buffer(f.data, f.len)) if f.len else b""
        direction = _DIRS.get(f.dir, "?")
        status = _STATUS.get(f.status, str(f.status))
        self.logger.debug("%s %s %s %d bytes: %s", self.label, direction, status, len(data),
                          data.hex(" "),
                          extra={"wire_dir": direction, "wire_status": status,
                                 "wire_t_ns": int(f.t_ns), "wire_bytes": data})


@ffi.def_extern()
def fap_py_trace(ctx: Any, f: Any) -> None:
    """The C trace hook: log the frame on its handle's logger."""
    try:
        ffi.from_handle(ctx).log(f)
    except Exception:  # pragma: no cover - never let an exception cross into C
        logging.getLogger("fap_py.wire").exception("trace hook failed")


def _inside_hook(frame: Optional[FrameType]) -> bool:
    """Whether ``frame`` is the hook or called from it."""
    code = fap_py_trace.__code__
    for _ in range(256):                 # handlers nest a few logging frames deep
        if frame is None:
            return False
        if frame.f_code is code:
            return True
        frame = frame.f_back
    return False


class _SigintGuard:
    """SIGINT's Python handler, deferring a Ctrl-C that lands inside the hook."""

    def __init__(self, previous: Any) -> None:
        self.previous = previous

    def __call__(self, signum: int, frame: Optional[FrameType]) -> None:
        if _inside_hook(frame):
            # raised here it would end in cffi: the C call's wrapper puts it back
            # once the call has returned (NativeHandle._call), and it is raised there
            DeferredSigint.pending = True
            return
        prev = self.previous
        if callable(prev):
            prev(signum, frame)
        elif prev != signal.SIG_IGN:
            raise KeyboardInterrupt


def _guard_sigint() -> None:
    """Wrap SIGINT's handler once (main thread only: signal.signal's rule)."""
    if threading.current_thread() is not threading.main_thread():
        return
    current = signal.getsignal(signal.SIGINT)
    if not isinstance(current, _SigintGuard) and current is not None:
        signal.signal(signal.SIGINT, _SigintGuard(current))


def tap_for(protocol: str, label: str) -> Optional[Tap]:
    """A :class:`Tap` when ``fap_py.wire.<protocol>`` logs DEBUG, else None."""
    logger = wire_logger(protocol)
    if not logger.isEnabledFor(logging.DEBUG):
        return None
    _guard_sigint()
    return Tap(logger, label)


def attach(setter: Callable[..., Any], handle: Any, protocol: str, label: str) -> Optional[Tap]:
    """``setter(handle, fap_py_trace, ctx)`` when the logger logs DEBUG; the
    returned Tap must live as long as the handle (None: no hook installed)."""
    tap = tap_for(protocol, label)
    if tap is not None:
        setter(handle, lib.fap_py_trace, tap.handle)
    return tap
