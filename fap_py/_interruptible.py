"""One blocking C open (or reopen) that Ctrl-C ends at once: the package's
one rule for it (:class:`fap_py.port.Port`, :class:`fap_py.fap.Master`,
the exec async and mikroC nodes).

A network open waits (the name lookup, the connect, the RFC 2217
negotiation: up to connect_ms + 2 x option_ms). On the main thread a C call
holds off Python's signal handlers until it returns, so the call runs in a
helper thread while the caller waits in slices; on KeyboardInterrupt (or any
exception there) the call's cancel fd (every wait of a network open watches
it) ends it at once, ``undo(rc)`` cleans up after it, and the exception goes
on.
"""
from __future__ import annotations

import os
import threading
from typing import Any, Callable, Optional

from ._handle import WAIT_SLICE
from ._native import lib


def interruptibly(call: Callable[[], Any], cancel_fd: int,
                  undo: Optional[Callable[[int], Any]] = None) -> int:
    """``call()`` (one blocking C call returning an int) in a helper thread;
    an exception in this one (Ctrl-C) writes ``cancel_fd``, waits for the call
    to end (at once: it watches the fd), runs ``undo(rc)`` and is raised."""
    result: list = []
    failed: list = []

    def run() -> None:
        try:
            result.append(int(call()))
        except BaseException as exc:   # handed to the waiting thread
            failed.append(exc)

    t = threading.Thread(target=run, name="fap-port-open", daemon=True)
    t.start()
    try:
        while t.is_alive():
            t.join(WAIT_SLICE)
    except BaseException:
        os.eventfd_write(cancel_fd, 1)
        t.join()   # every wait of a network open watches the cancel fd: it returns at once
        if undo is not None and result:
            undo(result[0])
        raise
    if failed:
        raise failed[0]
    return result[0]


def open_interruptibly(path: bytes, open_with: Callable[[int], Any],
                       undo: Optional[Callable[[int], Any]] = None) -> int:
    """``open_with(cancel_fd)``: an engine open whose options take a cancel fd
    watched only while it runs (``fapx_options.cancel_fd``,
    ``exec*Options.cancel_fd``; 0 = none). A URL (not a device, ``fap_port_kind``) opens in a
    helper thread with a fresh eventfd (:func:`interruptibly`), closed once the
    open returned; a device opens here (it does not wait)."""
    if lib.fap_port_kind(path) == lib.FAP_PORT_KIND_DEVICE:   # the port layer's reading
        return int(open_with(0))
    fd = os.eventfd(0, os.EFD_CLOEXEC | os.EFD_NONBLOCK)
    try:
        return interruptibly(lambda: open_with(fd), fd, undo)
    finally:
        os.close(fd)
