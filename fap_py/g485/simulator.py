"""G485 device simulator on a port: one thread per port, any number of devices.

The port is a device path opened through libfap's port layer (exclusive: a
second simulator or master on the same path gets a busy error), or a
pyserial URL/object or raw fd through the thin adapter. The thread blocks
in ``poll`` (no busy-waiting) on the port and on a wake-up pipe, feeds what
it reads to one parser (a chunk that is exactly one frame, the common case,
becomes its packet directly: ``codec.exact_packet``; the first pieces of a
request are held as bytes until it is whole: ``codec.frame_start``), hands every event to
every device on the port (each decides whether it is addressed) and writes
the replies. A partial frame left when the line goes idle is expired after
``idle_timeout``. On a shared bus the simulator also hears the other
devices' replies; they are addressed to the master (127) and ignored.
"""
from __future__ import annotations

import logging
import os
import select
import threading
import time
from typing import Any, Dict, Iterable, List, Optional, Sequence, Union

from ..errors import ClosedError, PortError
from ..rs485 import RS485
from .codec import MAX_SLAVE_ADDRESS, MIN_SLAVE_ADDRESS, Discarded, Packet, Parser, exact_packet, frame_start
from .device import SimDevice
from .errors import G485ValueError
from .transaction import timeout_arg, whole_arg
from .transport import PortIO, PortSpec, open_io

log = logging.getLogger("fap_py.g485.sim")

#: how many distinct whole frames a simulator keeps decoded (its fast path's cache)
_KNOWN_FRAMES = 64


class Simulator:
    """Runs :class:`SimDevice` objects on one port (path, pyserial URL/object or fd).

    Use as a context manager, or call :meth:`start` and :meth:`stop`.
    ``idle_timeout``: seconds of silence after which a partial frame is
    dropped (default 20 ms, or 5 character times at slow baud rates).
    ``rs485``: line options of a device path (:class:`fap_py.RS485`).
    """

    def __init__(self, port: PortSpec, devices: Iterable[SimDevice] = (), *, baudrate: int = 115200,
                 idle_timeout: Optional[float] = None, rs485: Optional[RS485] = None,
                 **serial_kwargs: Any) -> None:
        self._stopping = True  # until the port is open: stop() has nothing to do
        self._closed = False   # set by stop()/close(): add() and device() refuse then
        self.devices: List[SimDevice] = []
        try:
            for device in devices:
                self.add(device)
        except TypeError:
            raise G485ValueError("devices must be an iterable of SimDevice") from None
        idle = None if idle_timeout is None else timeout_arg(idle_timeout, "idle_timeout")
        self._io = open_io(port, baudrate, rs485=rs485, **serial_kwargs)
        self.name = self._io.name
        self.reopened = 0
        # silence after which a partial frame is dropped: 20 ms, or 5 characters at slow rates
        self.idle_timeout: float = max(0.02, 50.0 / self._io.baudrate) if idle is None else idle
        self._parser = Parser()
        self._thread: Optional[threading.Thread] = None
        self._stop_r, self._stop_w = os.pipe()
        self._stopping = False
        self.error: Optional[BaseException] = None
        self.replies_sent = 0
        self.events = 0  # parser events handled (packets and discards)

    def add(self, device: SimDevice) -> SimDevice:
        """Put a device on this port (IDs must differ). ClosedError once stopped."""
        self._check_open()
        if not isinstance(device, SimDevice):
            raise G485ValueError(f"a device must be a SimDevice, not {type(device).__name__}")
        if any(d.address == device.address for d in self.devices):
            raise G485ValueError(f"a device with ID {device.address} is already on this port")
        self.devices.append(device)
        return device

    def device(self, address: int) -> SimDevice:
        """The device currently answering at ``address`` (G485ValueError if none;
        ClosedError once stopped: nothing answers on a closed port)."""
        self._check_open()
        whole_arg(address, "address", MIN_SLAVE_ADDRESS, MAX_SLAVE_ADDRESS)
        for d in self.devices:
            if d.address == address:
                return d
        raise G485ValueError(f"no device answers at ID {address} on {self.name}")

    def _check_open(self) -> None:
        if self._closed:
            raise ClosedError(f"{getattr(self, 'name', 'simulator')}: simulator stopped "
                              "(its port is closed: make a new one)")

    # -- thread -------------------------------------------------------------

    def start(self) -> "Simulator":
        """Start the port thread. A stopped simulator has closed its port: make a
        new one (ClosedError here rather than a simulator that never answers)."""
        if self._stopping:
            raise ClosedError(f"{getattr(self, 'name', 'simulator')}: simulator stopped")
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name=f"g485-sim {self.name}", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and close the port (if the simulator opened it).
        Afterwards start(), add() and device() raise ClosedError."""
        if not self._stopping:
            self._stopping = True
            self._closed = True
            os.write(self._stop_w, b"x")
            if self._thread is not None:
                self._thread.join(5.0)
            self._io.close()
            os.close(self._stop_r)
            os.close(self._stop_w)

    def close(self) -> None:
        """The same as :meth:`stop` (the name every other fap_py object uses)."""
        self.stop()

    def __enter__(self) -> "Simulator":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __del__(self) -> None:
        try:
            self.stop()
        except Exception:  # pragma: no cover - half-built object, interpreter shutdown
            pass

    def _serve(self) -> None:
        try:
            if self._io.fd is not None:
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
            if fd is None or fd < 0:  # the device is gone: wait for it (no spinning)
                if stop_only.poll(50):
                    return
                self._reopen()
                continue
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            poller.register(stop_r, select.POLLIN)
            if not self._serve_open_fd(fd, poller, stop_only):
                return

    def _serve_open_fd(self, fd: int, poller: "select.poll", stop_only: "select.poll") -> bool:
        """Serve until stopped (False) or until the port was opened again (True)."""
        stop_r = self._stop_r
        parser = self._parser
        io = self._io
        read = io.read_nowait
        dispatch = self._dispatch
        # a master polls with the same few requests: their packets are made once (a Packet
        # is immutable); bounded, so a stream of distinct frames cannot grow it
        known: Dict[bytes, Packet] = {}
        held = b""  # a request's first bytes, read in pieces (codec.frame_start), not parsed yet
        while True:
            ready = poller.poll(self.idle_timeout * 1000.0 if held or parser.buffered else None)
            if not ready:
                if held:  # the rest never came: the Parser holds it now (no event) and drops it
                    parser.feed(held)
                    held = b""
                dispatch(parser.expire())
                continue
            if (len(ready) != 1 or ready[0][0] != fd) and any(rfd == stop_r for rfd, _ in ready):
                return False
            try:
                data = read(4096)
            except PortError:
                if self._stopping:
                    return False
                data = b""
            else:
                if not data and not any(flags & (select.POLLHUP | select.POLLERR) for _, flags in ready):
                    continue  # a spurious wake-up
            if data:
                if held:
                    data = held + data
                    held = b""
                if not parser.buffered:
                    # fast paths: the chunk is exactly one frame (the common case), or the
                    # start of one (a paced line): no Parser pass
                    packet = known.get(data)
                    if packet is None:
                        packet = exact_packet(data)
                        if packet is not None and len(known) < _KNOWN_FRAMES:
                            known[data] = packet
                    if packet is not None:
                        dispatch((packet,))
                        continue
                    if frame_start(data):
                        held = data
                        continue
                dispatch(parser.feed(data))
                continue
            # hung up (EIO or end of file): nobody on the other side of the pty yet, or
            # the port was disconnected (the port layer has closed its fd, whose number
            # may be reused: never poll it again); wait (no spinning), then try the path again
            if stop_only.poll(50):
                return False
            if isinstance(io, PortIO):
                self._reopen()
                return True

    def _reopen(self) -> bool:
        if not isinstance(self._io, PortIO):
            return False  # a raw fd or pyserial object: wait for the other side
        try:
            self._io.reopen()
        except PortError:
            return False  # not back yet
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
        if not events:
            return
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
