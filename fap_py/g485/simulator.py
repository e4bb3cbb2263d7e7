"""G485 device simulator on a port: one thread per port, any number of devices.

The thread blocks in ``poll`` (no busy-waiting) on the port and on a
wake-up pipe, feeds what it reads to one parser (a chunk that is exactly one
frame, the common case, becomes its packet directly: ``codec.exact_packet``),
hands every event to every device on the port (each decides whether it is
addressed) and writes the replies. A partial frame left when the line goes idle is expired after
``idle_timeout``. On a shared bus the simulator also hears the other
devices' replies; they are addressed to the master (127) and ignored.
"""
from __future__ import annotations

import errno
import logging
import os
import select
import threading
import time
from typing import Any, Iterable, List, Optional, Sequence, Union

from .codec import Discarded, Packet, Parser, exact_packet
from .device import SimDevice
from ..errors import PortError
from .errors import G485ValueError
from .transport import PortSpec, Transport

log = logging.getLogger("fap_py.g485.sim")


class Simulator:
    """Runs :class:`SimDevice` objects on one port (path, pyserial URL/object or fd).

    Use as a context manager, or call :meth:`start` and :meth:`stop`.
    ``idle_timeout``: seconds of silence after which a partial frame is
    dropped (default 20 ms, or 5 character times at slow baud rates).
    """

    def __init__(self, port: PortSpec, devices: Iterable[SimDevice] = (), *, baudrate: int = 115200,
                 idle_timeout: Optional[float] = None, **serial_kwargs: Any) -> None:
        self._io = Transport(port, baudrate=baudrate, **serial_kwargs)
        self.name = self._io.name
        # a port opened by path can be opened again after it hung up (a disconnect)
        self._reopen_args = ((self.name,), dict(baudrate=baudrate, **serial_kwargs)) \
            if isinstance(port, (str, os.PathLike)) else None
        self.reopened = 0
        self.devices: List[SimDevice] = []
        for device in devices:
            self.add(device)
        # silence after which a partial frame is dropped: 20 ms, or 5 characters at slow rates
        self.idle_timeout = idle_timeout if idle_timeout is not None else max(0.02, 50.0 / baudrate)
        self._parser = Parser()
        self._thread: Optional[threading.Thread] = None
        self._stop_r, self._stop_w = os.pipe()
        self._stopping = False
        self.error: Optional[BaseException] = None
        self.replies_sent = 0
        self.events = 0  # parser events handled (packets and discards)

    def add(self, device: SimDevice) -> SimDevice:
        """Put a device on this port (IDs must differ)."""
        if any(d.address == device.address for d in self.devices):
            raise G485ValueError(f"a device with ID {device.address} is already on {self.name}")
        self.devices.append(device)
        return device

    def device(self, address: int) -> SimDevice:
        """The device currently answering at ``address``."""
        for d in self.devices:
            if d.address == address:
                return d
        raise KeyError(address)

    # -- thread -------------------------------------------------------------

    def start(self) -> "Simulator":
        """Start the port thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name=f"g485-sim {self.name}", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the port (if the simulator opened it)."""
        if not self._stopping:
            self._stopping = True
            os.write(self._stop_w, b"x")
            if self._thread is not None:
                self._thread.join(5.0)
            self._io.close()
            os.close(self._stop_r)
            os.close(self._stop_w)

    def __enter__(self) -> "Simulator":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _serve(self) -> None:
        try:
            if self._io.fast:
                self._serve_fd()
            else:
                self._serve_generic()
        except Exception as exc:  # reported, not swallowed: tests check .error
            if not self._stopping:
                self.error = exc
                log.error("%s simulator stopped: %s", self.name, exc)

    def _serve_fd(self) -> None:
        stop_r = self._stop_r
        stop_only = select.poll()
        stop_only.register(stop_r, select.POLLIN)
        while True:  # once per (re)opened port
            fd = self._io.fd
            assert fd is not None
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            poller.register(stop_r, select.POLLIN)
            if not self._serve_open_fd(fd, poller, stop_only):
                return

    def _serve_open_fd(self, fd: int, poller: "select.poll", stop_only: "select.poll") -> bool:
        """Serve until stopped (False) or until the port was opened again (True)."""
        stop_r = self._stop_r
        parser = self._parser
        while True:
            ready = poller.poll(self.idle_timeout * 1000.0 if parser.buffered else None)
            if not ready:
                self._dispatch(parser.expire())
                continue
            for rfd, flags in ready:
                if rfd == stop_r:
                    return False
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    if self._stopping:
                        return False
                    if not flags & (select.POLLHUP | select.POLLERR):
                        raise PortError(exc.errno or errno.EIO, None, self.name) from None
                    data = b""
                if data:
                    # fast path: the chunk is exactly one frame (the common case), no Parser pass
                    packet = None if parser.buffered else exact_packet(data)
                    self._dispatch(parser.feed(data) if packet is None else (packet,))
                    continue
                # hung up (EIO or end of file): nobody on the other side of the pty yet, or
                # the port was disconnected; wait (no spinning), then try the path again
                if stop_only.poll(50):
                    return False
                if self._reopen():
                    return True

    def _reopen(self) -> bool:
        if self._reopen_args is None:
            return False
        args, kwargs = self._reopen_args
        try:
            fresh = Transport(*args, **kwargs)
        except PortError:
            return False  # not back yet
        if not fresh.fast:
            fresh.close()
            return False
        self._io.close()
        self._io = fresh
        self._parser.clear()
        self.reopened += 1
        log.info("%s reopened after a hang-up", self.name)
        return True

    def _serve_generic(self) -> None:
        while not self._stopping:
            deadline = time.monotonic() + (self.idle_timeout if self._parser.buffered else 0.05)
            data = self._io.read_some(4096, deadline)
            if data:
                self._dispatch(self._parser.feed(data))
            elif self._parser.buffered:
                self._dispatch(self._parser.expire())

    def _dispatch(self, events: Sequence[Union[Packet, Discarded]]) -> None:
        debug = log.isEnabledFor(logging.DEBUG)
        for ev in events:
            if debug:
                if isinstance(ev, Packet):
                    log.debug("%s rx %s %s", self.name, ev.kind.value, ev.raw.hex(" "))
                elif isinstance(ev, Discarded):
                    log.debug("%s rx discarded (%s, %s) %s", self.name, ev.issue.name, ev.detail,
                              ev.data.hex(" "))
            for device in self.devices:
                reply = device.handle(ev)
                if reply is not None:
                    if debug:
                        log.debug("%s tx device %d: %s", self.name, device.address, reply.hex(" "))
                    self.replies_sent += 1  # counted first: the master may look once it has the reply
                    try:
                        self._io.write(reply)
                    except PortError as exc:  # the port went away: the master will retry
                        log.warning("%s reply lost: %s", self.name, exc)
        self.events += len(events)
