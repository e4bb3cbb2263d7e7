"""The bus side of the daemon: one engine per protocol, one transaction at a time. Private.

Each backend opens the port through the protocol's own binding (the C engines:
:class:`fap_py.execasync.Master`, :class:`fap_py.mikroc.Master`; the C port layer
for ``raw``), so the protocol's framing rules decide where a reply ends. A backend
turns a checked request (``check``) into one atomic transaction (``run``, a
coroutine on the daemon's loop: no worker thread) and reports every frame it
sends or receives to ``on_frame`` (the monitor tap).
"""
from __future__ import annotations

import asyncio
import logging
import operator
import time
from dataclasses import asdict, dataclass, fields
from typing import Any, Callable, Dict, Optional, Tuple

from .. import _trace
from ..errors import FapTimeoutError
from ..rs485 import RS485
from ._errors import ProtocolError
from ._wire import hex_field, num_field

log = logging.getLogger("fap_py.serve")

#: on_frame(direction "tx"/"rx", status, t_ns CLOCK_MONOTONIC, bytes)
FrameSink = Callable[[str, str, int, bytes], None]


@dataclass(frozen=True)
class Job:
    """A checked request: the op and its arguments."""

    op: str
    args: Dict[str, Any]


class _FrameTap(_trace.Tap):
    """The C trace hook's ctx: every frame goes to the daemon's sink (and the wire log)."""

    def __init__(self, sink: FrameSink, protocol: str, label: str) -> None:
        super().__init__(_trace.wire_logger(protocol), label)
        self.sink = sink

    def log(self, f: Any) -> None:
        from .._native import ffi

        data = bytes(ffi.buffer(f.data, f.len)) if f.len else b""
        self.sink(_trace._DIRS.get(f.dir, "?"), _trace._STATUS.get(f.status, str(f.status)),
                  int(f.t_ns), data)
        if self.logger.isEnabledFor(logging.DEBUG):
            super().log(f)


def _counts_delta(names: Tuple[str, ...], before: Tuple[int, ...], after: Tuple[int, ...]) -> Dict[str, int]:
    return {k: a - b for k, b, a in zip(names, before, after) if a != b}


def _stats_delta(before: Any, after: Any) -> Dict[str, int]:
    # vars(), not asdict(): the counters are flat ints, asdict's deep copy cost ~20 µs a call
    a, b = vars(after), vars(before)
    return {k: a[k] - b[k] for k in a if a[k] != b[k]}


class Backend:
    """What the daemon needs of a protocol engine."""

    name = "?"
    #: the slaves a polling master lists (FAP: ``--slaves``)
    slaves: tuple = ()
    #: the engine's C trace hook feeds on_frame (see :meth:`_sync_hook`)
    _hooked = False
    _tapped = False
    _wire_log: Optional[logging.Logger] = None    #: the engine's wire logger (with a hook)
    #: the engine counter (in an answer's ``stats``) that counts frames nobody asked for
    LATE_COUNTER = "unexpected"
    #: ops answered at once, without the bus
    quick_ops: tuple = ()
    #: the hook runs on the engine's own thread, never the loop's: it can be taken off at once
    UNHOOK_AT_ONCE = False

    def __init__(self, port: str, baud: int, rs485: Optional[RS485], timeout: float,
                 retries: int, on_frame: FrameSink) -> None:
        self.port, self.baud, self.rs485 = port, baud, rs485
        self.timeout, self.retries = timeout, retries
        self.on_frame = on_frame
        self.node: Any = None

    def open(self) -> None:
        raise NotImplementedError

    @property
    def tapped(self) -> bool:
        """A monitor is attached (the daemon sets it): frames go to ``on_frame``."""
        return self._tapped

    @tapped.setter
    def tapped(self, on: bool) -> None:
        self._tapped = on
        if on or self.UNHOOK_AT_ONCE:   # never from inside the hook (C forbids it): on comes
            self._sync_hook()           # from a request; off waits for a transaction's start

    def _wants_hook(self) -> bool:
        return self._tapped or (self._wire_log is not None and self._wire_log.isEnabledFor(logging.DEBUG))

    def _sync_hook(self) -> None:
        """Install the C trace hook only while someone reads frames (a monitor, the
        wire log at DEBUG): without it a transaction's two frames cost no Python call.
        Turned off before a transaction, never from inside the hook (C forbids that)."""
        want = self._wants_hook()
        if want != self._hooked and self.node is not None and getattr(self, "_tap", None) is not None:
            self._set_hook(want)
            self._hooked = want

    def _set_hook(self, on: bool) -> None:
        """Install (True) or remove the engine's trace hook; engines with one override."""

    def close(self) -> None:
        if self.node is not None:
            self.node.close()

    def reopen(self) -> None:
        self.node.reopen()

    def fd(self) -> int:
        return self.node.fileno()

    def release_fd(self) -> None:
        """Before the daemon watches :meth:`fd` itself (late replies): an engine that
        keeps its own reader there between transactions takes it off."""

    def flush(self) -> None:
        """Drop input nobody asked for (a late reply)."""

    def check(self, op: str, msg: Dict[str, Any]) -> Job:
        raise NotImplementedError

    async def run(self, job: Job) -> Dict[str, Any]:
        raise NotImplementedError

    def quick(self, op: str, msg: Dict[str, Any]) -> Dict[str, Any]:
        raise ProtocolError(f"unknown op {op!r}")

    def counters(self) -> Dict[str, int]:
        """The engine's counters (its ``stats``) as a dict."""
        return asdict(self.node.stats) if self.node is not None else {}

    def info(self) -> Dict[str, Any]:
        """Fields the welcome carries for this protocol."""
        return {}

    def attach(self, publish: Callable[[Dict[str, Any]], None],
               port_event: Callable[[bool], None]) -> None:
        """Start what runs beside the transactions (FAP: the messages slaves send); each
        message for every client goes to ``publish``; an engine that reopens its port by
        itself reports ``port_event(False)`` when it lost it and ``(True)`` when it is
        back (the daemon tells its clients as for the others). Runs in the loop, after
        open()."""


class ExecBackend(Backend):
    """exec async: :class:`fap_py.execasync.Master` (sequence numbers, retries) on the port."""

    name = "exec"
    quick_ops = ("next_seq",)

    def open(self) -> None:
        from .. import execasync

        self._x = execasync
        self.node = execasync.Master(self.port, self.baud, timeout=self.timeout,
                                     retries=self.retries, rs485=self.rs485)
        self._tap = _FrameTap(self.on_frame, "exec", f"fap serve {self.port}")
        self._wire_log = self._tap.logger
        self._sync_hook()
        self._set = (self.timeout, self.retries)
        # the counters read straight from C into one struct (Master.stats builds a dataclass:
        # two of them a transaction were a tenth of the daemon's time)
        from .._native import ffi, lib

        self._names = tuple(f.name for f in fields(execasync.MasterStats))
        self._get = operator.attrgetter(*self._names)
        self._st = ffi.new("execMasterStats *")
        self._get_stats = lib.execMasterGetStats

    def _counts(self) -> Tuple[int, ...]:
        self.node._call(self._get_stats, self._st)
        return self._get(self._st)

    def _set_hook(self, on: bool) -> None:
        from .._native import ffi, lib

        with self.node._using() as h:
            if on:
                lib.execMasterSetTrace(h, lib.fap_py_trace, self._tap.handle)
            else:
                lib.execMasterSetTrace(h, ffi.NULL, ffi.NULL)

    def flush(self) -> None:
        from .._native import lib

        with self.node._using() as h:
            lib.fap_port_flush(lib.execMasterPort(h))

    def release_fd(self) -> None:
        self.node._adetach()               # atransact's reader, kept between transactions

    def check(self, op: str, msg: Dict[str, Any]) -> Job:
        x = self._x
        if op == "transact":
            node = num_field(msg, "node", x.NODE_MIN, x.NODE_MAX, integer=True)
            if node is None:
                raise ProtocolError("transact: field 'node' is missing")
            return Job(op, {"node": node, "data": hex_field(msg, "data", x.MAX_DATA),
                            "timeout": num_field(msg, "timeout", 1e-6, 3600.0),
                            "retries": num_field(msg, "retries", 0, 1000, integer=True)})
        if op == "broadcast":
            return Job(op, {"data": hex_field(msg, "data", x.MAX_DATA)})
        raise ProtocolError(f"unknown op {op!r} for protocol exec (transact, broadcast, next_seq)")

    def quick(self, op: str, msg: Dict[str, Any]) -> Dict[str, Any]:
        node = num_field(msg, "node", self._x.NODE_MIN, self._x.BROADCAST, integer=True)
        if node is None:
            raise ProtocolError("next_seq: field 'node' is missing")
        return {"seq": self.node.next_seq(node)}

    async def run(self, job: Job) -> Dict[str, Any]:
        m = self.node
        if self._hooked != self._wants_hook():
            self._sync_hook()
        before = self._counts()
        out: Dict[str, Any] = {}
        try:
            if job.op == "broadcast":
                await m.abroadcast(job.args["data"])
            else:
                a = job.args
                want = (self.timeout if a["timeout"] is None else a["timeout"],
                        self.retries if a["retries"] is None else a["retries"])
                if want != self._set:
                    m.set_timeout(*want)
                    self._set = want
                out["seq"] = m.next_seq(a["node"])
                out["data"] = (await m.atransact(a["node"], a["data"])).hex()
        except BaseException as exc:
            exc.daemon_fields = {"stats": _counts_delta(self._names, before, self._counts()),   # type: ignore[attr-defined]
                                 **out}
            raise
        out["stats"] = _counts_delta(self._names, before, self._counts())
        return out


class RawBackend(Backend):
    """raw bytes on the C port layer (:class:`fap_py.port.Port`): a request and a reply
    rule (``length`` bytes, a ``terminator``, or an ``idle`` gap), or a send alone."""

    name = "raw"
    MAX = 4096

    def open(self) -> None:
        from ..port import Port

        self.node = Port(self.port, self.baud, self.rs485)

    def flush(self) -> None:
        self.node.flush_input()

    def check(self, op: str, msg: Dict[str, Any]) -> Job:
        data = hex_field(msg, "data", self.MAX)
        if op == "send":
            if not data:
                raise ProtocolError("send: field 'data' is empty")
            return Job(op, {"data": data})
        if op != "transact":
            raise ProtocolError(f"unknown op {op!r} for protocol raw (transact, send)")
        length = num_field(msg, "length", 1, self.MAX, integer=True)
        term = hex_field(msg, "terminator", 16, default=None) if "terminator" in msg else None
        idle = num_field(msg, "idle", 1e-6, 10.0)
        if sum(x is not None for x in (length, term, idle)) != 1:
            raise ProtocolError("transact: give exactly one reply rule: length, terminator or idle")
        if term is not None and not term:
            raise ProtocolError("transact: an empty terminator")
        return Job(op, {"data": data, "length": length, "terminator": term, "idle": idle,
                        "max": num_field(msg, "max", 1, self.MAX, self.MAX, integer=True),
                        "timeout": num_field(msg, "timeout", 1e-6, 3600.0, self.timeout)})

    async def run(self, job: Job) -> Dict[str, Any]:
        p, a = self.node, job.args
        p.flush_input()
        self.on_frame("tx", "ok", time.monotonic_ns(), a["data"])
        p.write(a["data"])
        if job.op == "send":
            return {}
        got = bytearray()
        deadline = time.monotonic() + a["timeout"]
        most = a["max"] if a["length"] is None else a["length"]
        while len(got) < most:
            if a["terminator"] is not None and got.find(a["terminator"]) >= 0:
                got = got[:got.find(a["terminator"]) + len(a["terminator"])]
                break
            now = time.monotonic()
            wait = deadline - now
            if a["idle"] is not None and got:
                wait = min(wait, a["idle"])
            if wait <= 0 or not await p.await_readable(wait):
                if a["idle"] is not None and got:
                    break                       # the gap ended the reply
                if time.monotonic() >= deadline:
                    if got:
                        self.on_frame("rx", "truncated", time.monotonic_ns(), bytes(got))
                    raise FapTimeoutError(f"{self.port}: reply incomplete within {a['timeout']} s "
                                          f"({len(got)} bytes)")
                continue
            got += p.read_until(min(most - len(got), self.MAX), 0)
        self.on_frame("rx", "ok", time.monotonic_ns(), bytes(got))
        return {"data": bytes(got).hex()}


class MikrocBackend(Backend):
    """mikroC: :class:`fap_py.mikroc.Master`; a request and its reply, or a send alone."""

    name = "mikroc"

    def open(self) -> None:
        from .. import mikroc

        self._m = mikroc
        self.node = mikroc.Master(self.port, self.baud, rs485=self.rs485)
        self._tap = _FrameTap(self.on_frame, "mikroc", f"fap serve {self.port}")
        self._wire_log = self._tap.logger
        self._sync_hook()

    def _set_hook(self, on: bool) -> None:
        from .._native import ffi, lib

        if on:
            lib.mikrocRS485_CtxSetTrace(self.node._ctx, lib.fap_py_trace, self._tap.handle)
        else:
            lib.mikrocRS485_CtxSetTrace(self.node._ctx, ffi.NULL, ffi.NULL)

    def flush(self) -> None:
        from .._native import lib

        self.node._call(lambda _h: lib.mikrocRS485_CtxResetRx(self.node._ctx))

    def check(self, op: str, msg: Dict[str, Any]) -> Job:
        m = self._m
        if op not in ("request", "send"):
            raise ProtocolError(f"unknown op {op!r} for protocol mikroc (request, send)")
        address = num_field(msg, "address", m.NODE_MIN, m.NODE_MAX, integer=True)
        if address is None:
            raise ProtocolError(f"{op}: field 'address' is missing")
        return Job(op, {"address": address, "data": hex_field(msg, "data", m.MAX_DATA),
                        "timeout": num_field(msg, "timeout", 1e-6, 3600.0, self.timeout)})

    async def run(self, job: Job) -> Dict[str, Any]:
        a = job.args
        if self._hooked != self._wants_hook():
            self._sync_hook()
        before = self.node.stats
        try:
            if job.op == "send":
                self.node.send(a["address"], a["data"])
                out: Dict[str, Any] = {}
            else:
                reply = await self.node.arequest(a["address"], a["data"], a["timeout"])
                out = {"address": reply.address, "data": reply.data.hex()}
        except BaseException as exc:
            exc.daemon_fields = {"stats": _stats_delta(before, self.node.stats)}   # type: ignore[attr-defined]
            raise
        out["stats"] = _stats_delta(before, self.node.stats)
        return out




class G485Backend(Backend):
    """Gicren G485: :class:`fap_py.g485.aio.AsyncG485Master` (the pure-Python session on the
    C port layer, driven by the loop's fd: no thread). Each documented transaction
    (handshake, read, write, error word, set; a scan, a sync write, an ID change, a
    broadcast Set as one whole sequence) is one atomic op ``g485`` with a ``method``."""

    name = "g485"
    METHODS = ("handshake", "read", "write", "error_word", "set", "scan", "sync_write",
               "change_id", "broadcast_set", "send_raw", "send_wake_up")
    quick_ops = ("believed_check_byte",)

    def quick(self, op: str, msg: Dict[str, Any]) -> Dict[str, Any]:
        address = num_field(msg, "address", 0, 255, integer=True)
        if address is None:
            raise ProtocolError(f"{op}: field 'address' is missing")
        return {"value": self.node.master.believed_check_byte(address)}

    def open(self) -> None:
        from ..g485.aio import AsyncG485Master

        self.node = AsyncG485Master(self.port, self.baud, timeout=self.timeout,
                                    retries=min(self.retries, 10), rs485=self.rs485)
        self.baud = self.node.master.io.baudrate

    #: the session counts a reply that came too late as an ignored frame
    LATE_COUNTER = "ignored_frames"

    def fd(self) -> int:
        # no late-reply watch on the fd: the asyncio driver keeps its own reader there
        return -1

    def flush(self) -> None:
        self.node.master.io.flush_input()

    def reopen(self) -> None:
        self.node.master.ready_io()

    def close(self) -> None:
        if self.node is not None:
            self.node.master.close()

    def counters(self) -> Dict[str, int]:
        return asdict(self.node.master.stats) if self.node is not None else {}

    def check(self, op: str, msg: Dict[str, Any]) -> Job:
        if op != "g485":
            raise ProtocolError(f"unknown op {op!r} for protocol g485 (g485 with a method)")
        method, args = msg.get("method"), msg.get("args", {})
        if method not in self.METHODS:
            raise ProtocolError(f"g485: method must be one of {', '.join(self.METHODS)}")
        if not isinstance(args, dict) or not all(isinstance(k, str) for k in args):
            raise ProtocolError("g485: args must be an object")
        for key in ("data",):
            if key in args:
                args[key] = hex_field(args, key, 256)
        if method == "sync_write":
            w = args.get("writes")
            if not isinstance(w, list) or not all(isinstance(x, list) and len(x) == 3 for x in w):
                raise ProtocolError("g485 sync_write: writes is a list of [address, register, hex]")
            args["writes"] = [(a, r, hex_field({"d": d}, "d", 256)) for a, r, d in w]
        return Job(method, args)

    async def run(self, job: Job) -> Dict[str, Any]:
        m, a = self.node, dict(job.args)
        s = m.master.session
        before = m.master.stats
        try:
            if job.op == "change_id":
                await m._run_all(s.change_id(a["address"], a["new_address"], a.get("save", False),
                                             a.get("check")))
                value: Any = None
            elif job.op == "broadcast_set":
                await m._run_all(s.broadcast_sets(a["command"], a.get("repeats", 1)))
                value = None
            elif job.op == "send_raw":
                m.master.send_raw(a["data"])
                value = None
            elif job.op == "send_wake_up":
                m.master.send_wake_up()
                value = None
            else:
                value = await getattr(m, job.op)(**a)
        except KeyError as exc:
            raise ProtocolError(f"g485 {job.op}: argument {exc} is missing") from None
        except TypeError as exc:
            raise ProtocolError(f"g485 {job.op}: {exc}") from None
        except BaseException as exc:
            exc.daemon_fields = {"stats": _stats_delta(before, m.master.stats)}   # type: ignore[attr-defined]
            raise
        if isinstance(value, (bytes, bytearray)):
            value = bytes(value).hex()
        return {"value": value, "stats": _stats_delta(before, m.master.stats)}



class FapBackend(Backend):
    """FAP: :class:`fap_py.fap.Master` polls the daemon's ``--slaves``. A client's ``send``
    queues a DATA frame for a slave (the engine sends it in the master's turn); what the
    slaves send, and the engine's events, go to every client (``fap_rx``, ``fap_event``):
    the bus's traffic for the master, as one master program would receive it."""

    name = "fap"
    quick_ops = ("slaves", "fap_stats", "tx_pending")

    def open(self) -> None:
        from .. import fap

        self._f = fap
        self.node = fap.Master(self.port, self.baud, slaves=list(self.slaves), rs485=self.rs485)
        self._tasks: list = []

    def fd(self) -> int:
        return -1                          # the pump keeps its reader on the notification fd

    def reopen(self) -> None:
        """The engine reopens the port by itself (PORT_LOST / PORT_REOPENED events)."""

    # The hook runs on the engine's own thread and takes the GIL for every frame: with no
    # reader it is off, or a loaded daemon's engine can wait for the GIL between a slave's
    # DATA and DATA_DONE, miss its byte gap and stall the bus for the DATA_DONE window
    # (seen in the volume test).
    UNHOOK_AT_ONCE = True

    def _set_hook(self, on: bool) -> None:
        from .._native import ffi, lib

        with self.node._using() as h:
            if on:
                lib.fapx_set_trace(h, lib.fap_py_trace, self._tap.handle)
            else:
                lib.fapx_set_trace(h, ffi.NULL, ffi.NULL)

    def info(self) -> Dict[str, Any]:
        return {"rs485_mode": self.node.rs485_mode.name, "slaves": self.node.slaves}

    def attach(self, publish: Callable[[Dict[str, Any]], None],
               port_event: Callable[[bool], None]) -> None:
        node = self.node
        kinds = self._f.EventKind
        loop = asyncio.get_running_loop()

        def from_engine(direction: str, status: str, t_ns: int, data: bytes) -> None:
            # the FAP engine's own thread: hand the frame to the loop, only while tapped
            if self.tapped:
                loop.call_soon_threadsafe(self.on_frame, direction, status, t_ns, data)

        self._tap = _FrameTap(from_engine, "fap", f"fap serve {self.port}")
        self._wire_log = self._tap.logger
        self._sync_hook()      # only while a monitor or the wire log at DEBUG reads frames

        async def messages() -> None:
            async for msg in node:
                publish({"event": "fap_rx", "source": msg.source, "data": msg.data.hex()})

        async def events() -> None:
            async for ev in node.aevents(None):
                # "slave", not "id": "id" is the request id a client matches answers by
                publish({"event": "fap_event", "kind": ev.kind.name, "slave": ev.id, "time_ns": ev.time_ns})
                if ev.kind in (kinds.PORT_LOST, kinds.PORT_REOPENED):
                    port_event(ev.kind == kinds.PORT_REOPENED)

        self._tasks = [loop.create_task(messages()), loop.create_task(events())]

    def close(self) -> None:
        for t in getattr(self, "_tasks", []):
            t.cancel()
        super().close()

    def check(self, op: str, msg: Dict[str, Any]) -> Job:
        f = self._f
        if op == "flush":
            return Job(op, {"timeout": num_field(msg, "timeout", 0, 3600.0, 10.0)})
        if op != "send":
            raise ProtocolError(f"unknown op {op!r} for protocol fap (send, flush, slaves, fap_stats)")
        to = num_field(msg, "to", 1, f.MAX_ID, integer=True)
        if to is None:
            raise ProtocolError("send: field 'to' is missing")
        data = hex_field(msg, "data", f.MAX_DATA)
        if not data:
            raise ProtocolError("send: field 'data' is empty (1..MAX_DATA bytes)")
        return Job(op, {"to": to, "data": data})

    def quick(self, op: str, msg: Dict[str, Any]) -> Dict[str, Any]:
        if op == "slaves":
            return {"slaves": self.node.slaves, "active": self.node.active_slaves}
        if op == "tx_pending":
            return {"tx_pending": self.node.tx_pending}
        return {"stats": asdict(self.node.stats)}

    async def run(self, job: Job) -> Dict[str, Any]:
        from ..errors import QueueFullError

        m = self.node
        if job.op == "flush":
            end = time.monotonic() + job.args["timeout"]
            while m.tx_pending:
                if time.monotonic() >= end:
                    raise FapTimeoutError(f"flush: still {m.tx_pending} queued after {job.args['timeout']} s")
                await asyncio.sleep(0.002)
            return {}
        end = time.monotonic() + 1.0
        while True:                        # the engine's transmit queue: room comes as it sends
            try:
                m.send(job.args["data"], job.args["to"])
                break
            except QueueFullError:
                if time.monotonic() >= end:
                    raise
                await asyncio.sleep(0.002)
        # its bus time: the DATA frame's bytes (10 bits each) and the frame overhead
        return {"_cost": (len(job.args["data"]) + 8) * 10 / max(self.baud, 1)}


BACKENDS = {b.name: b for b in (ExecBackend, RawBackend, MikrocBackend, G485Backend, FapBackend)}
#: protocols the issue names that this daemon does not run yet
NOT_YET: tuple = ()
