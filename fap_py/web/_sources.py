"""Where ``fap web``'s frames come from: one :class:`Source` per kind of input.

A source runs in its own thread (:meth:`Source.run`), decodes with the monitor
(:class:`fap_py.monitor.Monitor`, the same decoders as ``fap monitor``) and hands
the records to the hub; it never waits for a browser. A source with fault
controls (the simulator) also answers :meth:`faults`, :meth:`add_fault` and
:meth:`remove_fault`; a daemon (``fap serve``, :class:`DaemonSource`) answers
:meth:`clients`. A new kind of source is one more subclass.
"""
from __future__ import annotations

import copy
import logging
import os
import tempfile
import threading
import time
from typing import Any, Dict, Iterator, List, Optional

from .._validate import check_baud, check_int, check_path, check_seconds
from ..errors import InvalidTypeError, InvalidValueError
from ..monitor.core import Monitor
from ..monitor.session import LIVE_BAUD, protocol_choice
from ..monitor.sources import LivePort, capture_file, char_seconds
from ..vbus import CaptureEvent, CaptureFormatError, CaptureRecord, iter_capture, iter_capture_file
from ._hub import Hub

log = logging.getLogger("fap_py.web")

#: how often a followed capture file is looked at for new lines, seconds (the bus
#: flushes its capture at most 50 ms after a line)
TAIL_POLL_S = 0.02


class NoFaultsError(InvalidValueError):
    """This source has no fault controls (only a simulator has)."""


class NoClientsError(InvalidValueError):
    """This source has no clients to show (only a daemon has)."""


class Source:
    """One input of ``fap web``. Subclasses set :attr:`kind` and implement :meth:`run`."""

    kind = "source"
    #: the page shows fault switches
    has_faults = False
    #: a finished recording (the page shows a time slider), not a live input
    seekable = False
    #: the page shows the clients of a daemon
    has_clients = False

    def __init__(self, protocol: str = "auto", baud: int = 0) -> None:
        self.protocol = protocol_choice(protocol)
        self.baud = check_int(baud, "baud", 0, 2**32 - 1)
        self.monitor: Optional[Monitor] = None

    def describe(self) -> Dict[str, Any]:
        """What the page shows about the source (``/api/info``)."""
        return {"kind": self.kind, "protocol": self.protocol,
                "decoding": None if self.monitor is None else self.monitor.locked,
                "baud": self.baud, "faults": self.has_faults, "seekable": self.seekable,
                "clients": self.has_clients}

    def run(self, hub: Hub, stop: threading.Event) -> None:
        """Decode the input into ``hub`` until it ends or ``stop`` is set (a subclass's)."""
        self._check_run(hub, stop)
        raise InvalidValueError(f"{type(self).__name__} has no run(): a Source subclass implements it")

    def close(self) -> None:
        """Release what :meth:`open` took (called once the thread ended)."""

    def open(self) -> None:
        """Open the input (errors here, before the server starts: a bad path, a busy port)."""

    # -- fault controls (a simulator) -----------------------------------------
    def faults(self) -> Dict[str, Any]:
        raise NoFaultsError(f"a {self.kind} source has no fault controls")

    def add_fault(self, request: Dict[str, Any]) -> Dict[str, Any]:
        raise NoFaultsError(f"a {self.kind} source has no fault controls")

    def remove_fault(self, fid: Any) -> List[Dict[str, Any]]:
        raise NoFaultsError(f"a {self.kind} source has no fault controls")

    # -- clients (a daemon) ---------------------------------------------------
    def clients(self) -> Dict[str, Any]:
        raise NoClientsError(f"a {self.kind} source has no clients")

    # -- shared ---------------------------------------------------------------
    @staticmethod
    def _check_run(hub: Any, stop: Any) -> None:
        if not isinstance(hub, Hub):
            raise InvalidTypeError(f"hub must be the server's Hub, not {type(hub).__name__}")
        if not isinstance(stop, threading.Event):
            raise InvalidTypeError(f"stop must be a threading.Event, not {type(stop).__name__}")

    def _monitor(self, baud: int) -> Monitor:
        self.monitor = Monitor(self.protocol, baud)
        return self.monitor


class PortSource(Source):
    """A live serial port or URL, opened receive-only (as ``fap monitor --port``)."""

    kind = "port"

    def __init__(self, path: str, baud: int = 0, protocol: str = "auto", rs485: Any = None) -> None:
        super().__init__(protocol, baud)
        self.path = check_path(path, "port")
        self.baud = check_baud(baud) if baud else LIVE_BAUD
        self.rs485 = rs485
        self._live: Optional[LivePort] = None

    def describe(self) -> Dict[str, Any]:
        return {**super().describe(), "port": self.path}

    def open(self) -> None:
        self._live = LivePort(self.path, self.baud, self.rs485)

    def run(self, hub: Hub, stop: threading.Event) -> None:
        self._check_run(hub, stop)
        live = self._live
        if live is None:
            raise InvalidValueError("PortSource.run before open()")
        mon = self._monitor(live.baud)
        for chunk in live.chunks(mon.idle_deadline, None, stop.is_set):
            if chunk is None:
                hub.publish(mon.idle(live.now_ns()))
            else:
                hub.publish(mon.feed(chunk.data, chunk.t, chunk.char_s, chunk.port, chunk.now_ns))
        hub.publish(mon.finish())

    def close(self) -> None:
        if self._live is not None:
            self._live.close()


class DaemonSource(PortSource):
    """A bus ``fap serve`` owns (``fapd:///path.sock`` or ``fapd://host:port``): every frame
    it sends and receives through the daemon's passive tap (``fap monitor --port fapd://``),
    and its clients (weights, queues, shares of wire time, late replies) from its status."""

    kind = "daemon"
    has_clients = True

    def __init__(self, url: str, protocol: str = "auto", token: Optional[str] = None) -> None:
        from ..serve import is_daemon_url

        super().__init__(url, 0, protocol)
        if not is_daemon_url(self.path):
            raise InvalidValueError(f"a daemon source takes a fapd:// URL, not {self.path!r}")
        if token is not None and not isinstance(token, str):
            raise InvalidTypeError(f"token must be None or a str, not {type(token).__name__}")
        self.token = token

    def open(self) -> None:
        super().open()
        assert self._live is not None
        self.baud = self._live.baud          # the daemon's line speed, from its welcome

    def clients(self) -> Dict[str, Any]:
        """The daemon's status, as ``fap serve status --json`` prints it; this page's own
        connections to the daemon (the tap, the status calls) are left out of the list."""
        from ..serve import status

        st = status(self.path, token=self.token)
        mine = os.getpid()
        st["clients"] = [c for c in st.get("clients", ())
                         if not (c.get("pid") == mine and (c.get("monitor") or c.get("name") == "status"))]
        return st


class CaptureSource(Source):
    """A virtual-bus capture file (``fap bus --capture``), read whole: the page has a slider."""

    kind = "capture"
    seekable = True

    def __init__(self, path: str, protocol: str = "auto", baud: int = 0) -> None:
        super().__init__(protocol, baud)
        self.path = check_path(path, "capture")
        self.span: Optional[List[float]] = None
        self._chunks: Optional[Iterator[Any]] = None

    def describe(self) -> Dict[str, Any]:
        return {**super().describe(), "capture": self.path, "span": self.span}

    def open(self) -> None:
        # the header now: a missing or bad file is an error before the server starts
        cap_baud, chunks = capture_file(self.path)
        self.baud = self.baud or cap_baud
        self._chunks = chunks

    def run(self, hub: Hub, stop: threading.Event) -> None:
        self._check_run(hub, stop)
        if self._chunks is None:
            raise InvalidValueError("CaptureSource.run before open()")
        mon = self._monitor(self.baud)
        recs = []
        for chunk in self._chunks:
            if stop.is_set():
                return
            recs.extend(mon.feed(chunk.data, chunk.t, chunk.char_s, chunk.port, chunk.now_ns))
        recs.extend(mon.finish())
        times = [r.t for r in recs if r.t is not None]
        if times:
            self.span = [min(times), max(times)]
            hub.set_baud(self.baud, max(0.001, (self.span[1] - self.span[0]) / 100.0))
        else:
            hub.set_baud(self.baud)
        collisions = [e.t_us / 1e6 for e in iter_capture_file(self.path)
                      if isinstance(e, CaptureEvent) and e.kind == "collision"]
        # records and collisions in time order, so each collision finds its pending request
        ci = 0
        for i in range(0, len(recs), 512):
            part = recs[i:i + 512]
            last_t = next((r.t for r in reversed(part) if r.t is not None), None)
            while ci < len(collisions) and last_t is not None and collisions[ci] <= last_t:
                hub.collision(collisions[ci])
                ci += 1
            hub.publish(part)
        for t in collisions[ci:]:
            hub.collision(t)


def _has_line(path: str) -> bool:
    try:
        with open(path, "rb") as fh:
            return b"\n" in fh.read(4096)
    except OSError:
        return False


def _tail_lines(path: str, stop: threading.Event) -> Iterator[str]:
    """The lines of a file being written, as they come, until ``stop``."""
    with open(path, "r", encoding="ascii", errors="replace") as fh:
        rest = ""
        while not stop.is_set():
            data = fh.read(65536)
            if not data:
                stop.wait(TAIL_POLL_S)
                continue
            rest += data
            *lines, rest = rest.split("\n")
            if len(rest) > 65536:
                raise CaptureFormatError(f"{path}: a line longer than 64 KiB")
            yield from lines


def _follow_capture(src: Source, path: str, baud: int, hub: Hub, stop: threading.Event) -> None:
    """Decode a virtual-bus capture as the bus writes it (a tap), until ``stop``."""
    mon = src._monitor(baud)
    hub.set_baud(baud)
    char_s = char_seconds(baud)
    last_data = time.monotonic_ns()
    for item in iter_capture(_tail_lines(path, stop)):
        now = time.monotonic_ns()
        if isinstance(item, CaptureRecord):
            hub.publish(mon.feed(item.data, item.t_us / 1e6, char_s, item.port, now))
            last_data = now
        elif isinstance(item, CaptureEvent) and item.kind == "collision":
            hub.collision(item.t_us / 1e6)
        deadline = mon.idle_deadline()
        if deadline is not None and now >= deadline and now > last_data:
            hub.publish(mon.idle(now))
    hub.publish(mon.finish())


def _check_fault_request(request: Any) -> None:
    """A fault request from the page (the control socket's ``fault.add`` keys), checked the
    same for an in-process sim and one behind its control socket."""
    from ..sim import FaultError

    if not isinstance(request, dict):
        raise InvalidTypeError(f"a fault is a JSON object, not {type(request).__name__}")
    extra = set(request) - FAULT_KEYS
    if extra:
        raise FaultError(f"unknown key(s) {', '.join(sorted(map(str, extra)))} "
                         f"(known: {', '.join(sorted(FAULT_KEYS))})")
    if not isinstance(request.get("kind"), str):
        raise FaultError("a fault needs 'kind' (a str)")


class SimSource(Source):
    """A simulator (:class:`fap_py.sim.Sim`) run here from its config: its faults on the page.

    The frames come from a tap on the simulated bus: its virtual-bus capture
    (every byte with its sender and wire time, collisions as events), followed as it
    is written and decoded by the monitor. The bus must be virtual (the sim makes
    it); your master opens its ``master_port``.
    """

    kind = "sim"
    has_faults = True

    def __init__(self, config: Any, bus: Optional[str] = None, protocol: Optional[str] = None,
                 clock: Any = None) -> None:
        from ..sim import check_config, load

        if isinstance(config, (str, os.PathLike)):
            cfg = load(check_path(config, "config"))
        elif isinstance(config, dict):
            cfg = check_config(copy.deepcopy(config))
        else:
            raise InvalidTypeError(f"config must be a path or a dict, not {type(config).__name__}")
        buses = cfg["bus"]
        names = [b.get("name", f"bus{i}") for i, b in enumerate(buses)]
        if bus is not None and (not isinstance(bus, str) or bus not in names):
            raise InvalidValueError(f"bus must be one of {', '.join(names)}, not {bus!r}")
        self.bus_index = 0 if bus is None else names.index(bus)
        self.bus_name = names[self.bus_index]
        b = buses[self.bus_index]
        if "port" in b:
            raise InvalidValueError(f"bus {self.bus_name!r} is on a real port ({b['port']}): fap web "
                                    "taps a virtual bus the sim makes (use --port to watch a real one)")
        super().__init__(protocol or b["protocol"], 0)
        self._config = copy.deepcopy(cfg)
        self._clock = clock
        self._dir: Optional[str] = None
        self.capture: Optional[str] = None
        self.sim: Any = None

    def describe(self) -> Dict[str, Any]:
        sb = self.sim.buses[self.bus_index] if self.sim is not None and self.sim.buses else None
        return {**super().describe(), "bus": self.bus_name,
                "master_port": None if sb is None else sb.master_port,
                "nodes": [] if sb is None else sb.addresses,
                "fault_kinds": list(self.sim.allowed.get(self.bus_name, ())) if self.sim else []}

    def open(self) -> None:
        from ..sim import Sim

        virtual = self._config["bus"][self.bus_index].setdefault("virtual", {})
        if virtual.get("capture"):
            self.capture = check_path(virtual["capture"], "capture")
        else:
            self._dir = tempfile.mkdtemp(prefix="fap-web-")
            self.capture = virtual["capture"] = os.path.join(self._dir, "tap.cap")
        self.sim = Sim(self._config, clock=self._clock)
        self.baud = self.sim.buses[self.bus_index].vbus.baud

    def run(self, hub: Hub, stop: threading.Event) -> None:
        self._check_run(hub, stop)
        if self.capture is None:
            raise InvalidValueError("SimSource.run before open()")
        _follow_capture(self, self.capture, self.baud, hub, stop)

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None
        if self._dir is not None:
            for name in os.listdir(self._dir):
                os.unlink(os.path.join(self._dir, name))
            os.rmdir(self._dir)
            self._dir = None

    # -- faults: the sim's own table ------------------------------------------
    def faults(self) -> Dict[str, Any]:
        if self.sim is None:
            raise InvalidValueError("the sim is not running")
        st = self.sim.status()
        bus = next((b for b in st["buses"] if b["name"] == self.bus_name), None)
        return {"faults": [f for f in self.sim.faults_list() if f.get("bus") in (None, self.bus_name)],
                "kinds": list(self.sim.allowed.get(self.bus_name, ())),
                "nodes": [] if bus is None else bus["nodes"], "faults_applied": st["faults_applied"],
                "fault_changes": st["fault_changes"]}

    def add_fault(self, request: Dict[str, Any]) -> Dict[str, Any]:
        """Add a fault (the control socket's ``fault.add`` keys); its public record."""
        _check_fault_request(request)
        if self.sim is None:
            raise InvalidValueError("the sim is not running")
        kw = {k: request[k] for k in FAULT_KEYS - {"kind"} if k in request}
        kw.setdefault("bus", self.bus_name)
        return dict(self.sim.add_fault(request["kind"], **kw))

    def remove_fault(self, fid: Any) -> List[Dict[str, Any]]:
        """Remove fault ``fid`` (or ``"all"`` of this bus's); the removed records."""
        if self.sim is None:
            raise InvalidValueError("the sim is not running")
        if fid == "all":
            out: List[Dict[str, Any]] = []
            for f in self.faults()["faults"]:
                out += self.sim.remove_fault(f["id"])
            return out
        return list(self.sim.remove_fault(fid))


class SimControlSource(Source):
    """A sim running elsewhere (``fap sim CONFIG --control unix:PATH``): its faults through
    its control socket (docs/sim.md, "Control protocol"), its frames from the capture its
    bus writes (the config's ``virtual.capture``: ``tap``), followed as it grows."""

    kind = "sim"
    has_faults = True

    def __init__(self, control: str, tap: str, bus: Optional[str] = None, protocol: Optional[str] = None,
                 timeout: float = 5.0) -> None:
        if not isinstance(control, str) or not control.startswith("unix:") or len(control) <= 5 \
                or "\0" in control:
            raise InvalidValueError(f"control must be unix:PATH (fap sim --control), not {control!r}")
        if bus is not None and not isinstance(bus, str):
            raise InvalidTypeError(f"bus must be a bus name (str), not {type(bus).__name__}")
        super().__init__(protocol or "auto", 0)
        self.control, self.path = control, control[5:]
        self.tap = check_path(tap, "tap")
        self.timeout = check_seconds(timeout, "timeout")
        self.bus_name = bus
        self._explicit = protocol is not None
        self._status: Dict[str, Any] = {}

    def _request(self, obj: Dict[str, Any]) -> Dict[str, Any]:
        """One control request, one answer line (FileError: nobody answers there)."""
        import json
        import socket

        from ..errors import FileError
        from ..sim import FaultError

        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(self.timeout)
        try:
            try:
                s.connect(self.path)
                s.sendall(json.dumps(obj).encode() + b"\n")
                buf = b""
                while b"\n" not in buf:
                    data = s.recv(65536)
                    if not data or len(buf) > (1 << 22):
                        raise FaultError(f"{self.control}: no answer line from the sim")
                    buf += data
            except socket.timeout:
                raise FaultError(f"{self.control}: no answer within {self.timeout} s") from None
            except OSError as exc:
                raise FileError(exc.errno or 2, f"control socket: {exc.strerror} (is `fap sim "
                                f"--control {self.control}` running?)", self.path) from None
        finally:
            s.close()
        try:
            ans = json.loads(buf.split(b"\n", 1)[0])
        except ValueError:
            raise FaultError(f"{self.control}: the answer is not JSON") from None
        if not isinstance(ans, dict) or not ans.get("ok"):
            raise FaultError(str(ans.get("error") if isinstance(ans, dict) else ans))
        return ans

    def _bus(self) -> Dict[str, Any]:
        st = self._status = self._request({"cmd": "status"})
        buses = st.get("buses", [])
        names = [b.get("name") for b in buses]
        if not buses or (self.bus_name is not None and self.bus_name not in names):
            raise InvalidValueError(f"bus must be one of {', '.join(map(str, names))}, not {self.bus_name!r}")
        return buses[0] if self.bus_name is None else buses[names.index(self.bus_name)]

    def open(self) -> None:
        b = self._bus()
        self.bus_name = b["name"]
        if not self._explicit:
            self.protocol = protocol_choice(b["protocol"])
        # the tap's header has the bus's rate; a bus flushes its header within 50 ms of opening,
        # so a sim that just started gets up to `timeout` for it (then an empty file is said)
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline and not _has_line(self.tap):
            threading.Event().wait(TAIL_POLL_S)
        cap_baud, _unread = capture_file(self.tap)
        self.baud = cap_baud

    def describe(self) -> Dict[str, Any]:
        bus: Dict[str, Any] = next((b for b in self._status.get("buses", []) if b.get("name") == self.bus_name), {})
        return {**super().describe(), "bus": self.bus_name, "control": self.control, "tap": self.tap,
                "master_port": bus.get("master_port"), "nodes": [n["address"] for n in bus.get("nodes", [])]}

    def run(self, hub: Hub, stop: threading.Event) -> None:
        self._check_run(hub, stop)
        _follow_capture(self, self.tap, self.baud, hub, stop)

    def faults(self) -> Dict[str, Any]:
        b = self._bus()
        faults = self._request({"cmd": "fault.list"})["faults"]
        from ..errors import FapError
        from ..sim import plugin

        try:
            kinds = list(plugin(b["protocol"]).FAULTS)     # the kinds its protocol implements
        except FapError:                                   # a protocol this install lacks
            kinds = sorted({k for n in b.get("nodes", []) for k in n.get("faults", {})})
        return {"faults": [f for f in faults if f.get("bus") in (None, self.bus_name)], "kinds": kinds,
                "nodes": b.get("nodes", []), "faults_applied": self._status.get("faults_applied", {}),
                "fault_changes": self._status.get("fault_changes", 0)}

    def add_fault(self, request: Dict[str, Any]) -> Dict[str, Any]:
        _check_fault_request(request)
        req = {"cmd": "fault.add", "bus": self.bus_name, **request}
        return dict(self._request(req)["fault"])

    def remove_fault(self, fid: Any) -> List[Dict[str, Any]]:
        from ..sim import FaultError

        if fid != "all" and (isinstance(fid, bool) or not isinstance(fid, int)):
            raise FaultError(f"a fault id is an int or 'all', not {fid!r}")
        if fid == "all":
            out: List[Dict[str, Any]] = []
            for f in self.faults()["faults"]:
                out += self._request({"cmd": "fault.remove", "id": f["id"]})["removed"]
            return out
        return list(self._request({"cmd": "fault.remove", "id": fid})["removed"])


#: what a fault request may hold (the sim control socket's ``fault.add`` keys)
FAULT_KEYS = frozenset({"kind", "node", "bus", "probability", "ms", "seed"})


__all__ = ["CaptureSource", "DaemonSource", "NoClientsError", "NoFaultsError", "PortSource", "SimControlSource",
           "SimSource", "Source"]
