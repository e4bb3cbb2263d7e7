"""G485 device simulator on a port: one thread per port, any number of devices.

The thread blocks in ``poll`` (no busy-waiting) on the port and on a
wake-up pipe, feeds what it reads to one parser, hands every event to every
device on the port (each decides whether it is addressed) and writes the
replies. A partial frame left when the line goes idle is expired after
``idle_timeout``. On a shared bus the simulator also hears the other
devices' replies; they are addressed to the master (127) and ignored.
"""
from __future__ import annotations

import logging
import os
import select
import threading
import time
from typing import Any, Iterable, List, Optional

from .codec import Discarded, Packet, Parser
from .device import SimDevice
from .errors import G485ValueError
from .transport import PortSpec, Transport

log = logging.getLogger("fap_py.g485.sim")


class Simulator:
    """Runs :class:`SimDevice` objects on one port (path, pyserial URL/object or fd).

    Use as a context manager, or call :meth:`start` and :meth:`stop`.
    """

    def __init__(self, port: PortSpec, devices: Iterable[SimDevice] = (), *, baudrate: int = 115200,
                 idle_timeout: float = 0.02, **serial_kwargs: Any) -> None:
        self._io = Transport(port, baudrate=baudrate, **serial_kwargs)
        self.name = self._io.name
        self.devices: List[SimDevice] = []
        for device in devices:
            self.add(device)
        self.idle_timeout = idle_timeout
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
        fd = self._io.fd
        assert fd is not None
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        poller.register(self._stop_r, select.POLLIN)
        stop_r = self._stop_r
        stop_only = select.poll()
        stop_only.register(stop_r, select.POLLIN)
        while True:
            timeout = self.idle_timeout * 1000.0 if self._parser.buffered else None
            ready = poller.poll(timeout)
            if not ready:
                self._dispatch(self._parser.expire())
                continue
            for rfd, flags in ready:
                if rfd == stop_r:
                    return
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    continue
                except OSError as exc:
                    if self._stopping:
                        return
                    if flags & select.POLLHUP:
                        # the other side of a pty is not open (yet): wait instead of spinning
                        if stop_only.poll(50):
                            return
                        continue
                    raise exc
                if data:
                    self._dispatch(self._parser.feed(data))

    def _serve_generic(self) -> None:
        while not self._stopping:
            deadline = time.monotonic() + (self.idle_timeout if self._parser.buffered else 0.05)
            data = self._io.read_some(4096, deadline)
            if data:
                self._dispatch(self._parser.feed(data))
            elif self._parser.buffered:
                self._dispatch(self._parser.expire())

    def _dispatch(self, events: List) -> None:
        debug = log.isEnabledFor(logging.DEBUG)
        write = self._io.write
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
                    write(reply)
        self.events += len(events)
