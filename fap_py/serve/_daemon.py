"""The daemon: one asyncio loop owns the bus and serves every client. Private.

Listeners (Unix sockets, TCP) accept clients; each client says hello (version,
token, weight, priority), then sends requests. Bus requests go into the
client's bounded queue; one bus task takes them in the scheduler's order
(:mod:`._sched`: deficit round-robin by wire time) and runs each as one atomic
transaction on the protocol's engine (:mod:`._backends`). The answer goes back
on the connection that asked, matched by its id; a client that left loses its
answer, nobody else gets it. Hostile clients (garbage, oversized or half-sent
messages, floods, never reading) are cut off; the bus task never waits for a
client.
"""
from __future__ import annotations

import asyncio
import errno
import grp
import hmac
import logging
import os
import pwd
import select
import signal
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

from .._validate import check_baud, check_int, check_path, check_seconds
from ..errors import FapError, FapTimeoutError, InvalidTypeError, InvalidValueError, PortError, PortGoneError
from ..port import port_kind
from ..rs485 import DEFAULT_BAUD, RS485
from ._backends import BACKENDS, NOT_YET, Backend, Job
from ._errors import BadUrlError, ClientQueueFullError, DaemonError, ProtocolError
from ._lock import UucpLock
from ._sched import DEFAULT_QUANTUM, Scheduler
from ._url import Address, is_loopback, parse_listen
from ._wire import VERSION, MessageReader, pack

log = logging.getLogger("fap_py.serve")


@dataclass
class ServeConfig:
    """What ``fap serve`` runs (every field has a command-line option, docs/daemon.md)."""

    protocol: str
    port: str
    listen: List[str]
    baud: int = DEFAULT_BAUD
    rs485: Optional[RS485] = None
    timeout: float = 0.1            #: default reply timeout per attempt (s)
    retries: int = 3                #: default retries (exec)
    token_file: Optional[str] = None
    socket_mode: int = 0o660
    socket_owner: Optional[str] = None
    socket_group: Optional[str] = None
    lock_dir: Optional[str] = "/var/lock"   #: None: no UUCP lock file
    queue: int = 16                 #: requests a client may have waiting
    max_weight: int = 16
    max_priority: int = 3
    max_clients: int = 64
    hello_timeout: float = 5.0      #: a new connection must say hello within this
    body_timeout: float = 5.0       #: a started message must be complete within this
    write_limit: int = 1 << 20      #: bytes unread by a client before it is cut off
    quantum: float = DEFAULT_QUANTUM
    reopen_interval: float = 0.5
    slaves: List[int] = field(default_factory=list)
    metrics: Optional[str] = None   #: tcp://HOST:PORT of the Prometheus endpoint (None: none)

    def check(self) -> None:
        """Refuse a configuration that cannot run (InvalidValueError / InvalidTypeError)."""
        for name, kind in (("protocol", str), ("port", str), ("listen", list), ("baud", int),
                           ("timeout", (int, float)), ("retries", int), ("socket_mode", int),
                           ("quantum", (int, float)), ("hello_timeout", (int, float)),
                           ("body_timeout", (int, float)), ("write_limit", int),
                           ("reopen_interval", (int, float))):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, kind):
                raise InvalidTypeError(f"ServeConfig.{name}: {type(v).__name__} is not the right type")
        for name in ("token_file", "socket_owner", "socket_group", "lock_dir", "metrics"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, str):
                raise InvalidTypeError(f"ServeConfig.{name} must be a str or None")
        if self.rs485 is not None and not isinstance(self.rs485, RS485):
            raise InvalidTypeError("ServeConfig.rs485 must be an RS485 or None")
        if not all(isinstance(x, str) for x in self.listen):
            raise InvalidTypeError("ServeConfig.listen must be a list of str")
        check_path(self.port, "port")
        check_baud(self.baud)
        for name in ("timeout", "quantum", "hello_timeout", "body_timeout", "reopen_interval"):
            check_seconds(getattr(self, name), name, lo_open=True, hi=3600.0)
        check_int(self.retries, "retries", 0, 1000)
        check_int(self.write_limit, "write_limit", 1, 1 << 30)
        if self.protocol in NOT_YET:
            raise InvalidValueError(f"fap serve --protocol {self.protocol}: not served yet "
                                    f"(served: {', '.join(sorted(BACKENDS))})")
        if self.protocol not in BACKENDS:
            raise InvalidValueError(f"unknown protocol {self.protocol!r} (served: {', '.join(sorted(BACKENDS))})")
        if not self.listen:
            raise InvalidValueError("no --listen address (unix:PATH or tcp://HOST:PORT)")
        for text in self.listen:
            try:
                a = parse_listen(text)
            except BadUrlError as exc:           # a configuration error (exit 2), not a port's
                raise InvalidValueError(str(exc)) from None
            if a.kind == "tcp" and not is_loopback(a.host) and not self.token_file:
                raise InvalidValueError(f"--listen {text}: TCP beyond loopback needs --token-file")
        try:
            if self.socket_owner:
                pwd.getpwnam(self.socket_owner)
            if self.socket_group:
                grp.getgrnam(self.socket_group)
        except KeyError as exc:
            raise InvalidValueError(f"socket owner/group: no such user or group {exc}") from None
        if self.metrics is not None:
            try:
                m = parse_listen(self.metrics)
            except BadUrlError as exc:
                raise InvalidValueError(f"metrics: {exc}") from None
            if m.kind != "tcp":
                raise InvalidValueError("metrics: tcp://HOST:PORT")
        if self.token_file:
            self.token()
        if not isinstance(self.slaves, (list, tuple)) or not all(
                isinstance(i, int) and not isinstance(i, bool) for i in self.slaves):
            raise InvalidTypeError("ServeConfig.slaves must be a list of slave IDs")
        if self.protocol == "fap" and not self.slaves:
            raise InvalidValueError("fap serve --protocol fap needs --slaves IDS (the slaves it polls)")
        for name, lo in (("queue", 1), ("max_weight", 1), ("max_priority", 0), ("max_clients", 1),
                         ("socket_mode", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise InvalidValueError(f"{name} must be a whole number >= {lo}, not {v!r}")

    def token(self) -> Optional[str]:
        if not self.token_file:
            return None
        try:
            with open(self.token_file, encoding="utf-8") as f:
                tok = f.read().strip()
        except OSError as exc:
            raise PortError(exc.errno or errno.EIO, f"token file: {exc.strerror}", self.token_file) from None
        if not tok:
            raise InvalidValueError(f"{self.token_file}: the token file is empty")
        return tok


def _error_obj(exc: BaseException) -> Dict[str, Any]:
    out: Dict[str, Any] = {"type": type(exc).__name__, "message": str(exc)}
    if isinstance(exc, OSError) and exc.errno:
        out["errno"] = exc.errno
    # a protocol's error fields: mikroC's frame error (code, address), G485's check
    # mismatch (expected, got), error word (address, word) and frame error (frame)
    for attr in ("code", "address", "expected", "got", "word"):
        v = getattr(exc, attr, None)
        if isinstance(v, int) and not isinstance(v, bool):
            out[attr] = v
    frame = getattr(exc, "frame", None)
    if isinstance(frame, (bytes, bytearray)):
        out["frame"] = bytes(frame).hex()
    return out


@dataclass
class Pending:
    session: "Session"
    rid: Any
    job: Job
    queued: float


class Session:
    """One connected client."""

    def __init__(self, daemon: "Daemon", key: int, reader: asyncio.StreamReader,
                 writer: asyncio.StreamWriter, peer: str) -> None:
        self.daemon, self.key, self.reader, self.writer, self.peer = daemon, key, reader, writer, peer
        self.name = ""
        self.pid: Optional[int] = None
        self.uid: Optional[int] = None
        self.weight, self.priority = 1, 0
        self.joined = False
        self.monitor = False
        self.closed = False
        self.late = 0
        self.errors = 0
        self.replies = 0
        self.refused_full = 0
        self.in_flight = 0
        self.since = time.time()

    def send(self, obj: Dict[str, Any]) -> bool:
        """Queue a message for the client; never waits. A client that lets
        ``write_limit`` bytes pile up unread is cut off."""
        if self.closed:
            return False
        try:
            self.writer.write(pack(obj))
        except (OSError, RuntimeError):
            self.cut("write failed")
            return False
        if self.writer.transport.get_write_buffer_size() > self.daemon.config.write_limit:
            self.cut(f"does not read its answers ({self.daemon.config.write_limit} bytes unread)")
            return False
        return True

    def cut(self, why: str) -> None:
        if self.closed:
            return
        self.closed = True
        self.daemon.counters["cut_off"] += 1
        log.warning("client %d (%s): cut off: %s", self.key, self.peer, why)
        self.writer.transport.abort()

    def status(self, total_wire: float) -> Dict[str, Any]:
        sh = self.daemon.sched.share(self.key) if self.joined else None
        wire = sh.wire_time if sh else 0.0
        return {"client": self.key, "name": self.name, "peer": self.peer, "pid": self.pid,
                "uid": self.uid, "weight": self.weight, "priority": self.priority,
                "monitor": self.monitor, "queued": len(sh.queue) if sh else 0,
                "in_flight": self.in_flight, "transactions": sh.transactions if sh else 0,
                "wire_time": round(wire, 6), "share": round(wire / total_wire, 4) if total_wire else 0.0,
                "late": self.late, "errors": self.errors, "queue_full": self.refused_full,
                "connected_s": round(time.time() - self.since, 1)}


class Daemon:
    """The bus daemon: ``await start()``, then ``await wait_closed()``; ``stop()`` ends it."""

    def __init__(self, config: ServeConfig) -> None:
        if not isinstance(config, ServeConfig):
            raise InvalidTypeError(f"config must be a ServeConfig, not {type(config).__name__}")
        config.check()
        self.config = config
        self.sched = Scheduler(config.quantum)
        self.sessions: Dict[int, Session] = {}
        self._next_key = 1
        self._token = config.token()
        self._servers: List[asyncio.AbstractServer] = []
        self._unix_paths: List[str] = []
        self._wake = asyncio.Event()
        self._stopped = asyncio.Event()
        self._bus_task: Optional["asyncio.Task[None]"] = None
        self._late_owner: Optional[Session] = None
        self._timed_out: Optional[Session] = None     # whose transaction timed out last
        self._late_fd = -1
        self.port_state = "closed"
        self.counters = {"transactions": 0, "errors": 0, "late": 0, "refused": 0, "cut_off": 0,
                         "queue_full": 0, "dropped": 0, "reopens": 0, "port_gone": 0, "cancelled": 0}
        # the transaction on the bus now, its task, and the one its client cancelled
        self._current: Optional[Pending] = None
        self._running: Optional["asyncio.Future[Any]"] = None
        self._cancelled: Optional[Pending] = None
        self._closing = False
        self.wire_time = 0.0
        self.started = time.time()
        self.listening: List[str] = []
        self.metrics_url: Optional[str] = None
        self._lock: Optional[UucpLock] = None
        self.backend: Backend = BACKENDS[config.protocol](
            config.port, config.baud, config.rs485, config.timeout, config.retries, self._frame)
        self.backend.slaves = tuple(config.slaves)

    # -- life ------------------------------------------------------------------

    def open_port(self) -> None:
        """Take the device: the UUCP lock file, then the engine's open (flock + TIOCEXCL)."""
        c = self.config
        if c.lock_dir and port_kind(c.port) == "device":     # a network port has no lock file
            self._lock = UucpLock(c.port, c.lock_dir)
            self._lock.acquire()
        try:
            self.backend.open()
        except BaseException:
            if self._lock:
                self._lock.release()
            raise
        self.port_state = "open"
        log.info("%s: %s on %s at %d baud", c.protocol, type(self.backend).__name__, c.port, c.baud)

    async def start(self) -> None:
        self.open_port()
        try:
            for text in self.config.listen:
                await self._listen(parse_listen(text))
        except BaseException:
            self.close_now()
            raise
        if self.config.metrics:
            await self._listen_metrics(parse_listen(self.config.metrics))
        self._bus_task = asyncio.get_running_loop().create_task(self._bus())
        self.backend.attach(self._broadcast_event, self._engine_port)

    async def _listen(self, addr: Address) -> None:
        c = self.config
        if addr.kind == "unix":
            path = addr.path
            if os.path.exists(path):
                probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                try:
                    probe.connect(path)
                except OSError:
                    os.unlink(path)          # a stale socket file of a daemon that died
                else:
                    raise DaemonError(f"{path}: another daemon listens here", path, errno.EADDRINUSE)
                finally:
                    probe.close()
            srv = await asyncio.start_unix_server(lambda r, w: self._client(r, w), path)
            os.chmod(path, c.socket_mode)
            if c.socket_owner or c.socket_group:
                uid = pwd.getpwnam(c.socket_owner).pw_uid if c.socket_owner else -1
                gid = grp.getgrnam(c.socket_group).gr_gid if c.socket_group else -1
                os.chown(path, uid, gid)
            self._unix_paths.append(path)
        else:
            try:
                srv = await asyncio.start_server(lambda r, w: self._client(r, w), addr.host, addr.port)
            except OSError as exc:
                raise DaemonError(f"{addr}: cannot listen: {exc.strerror}", str(addr),
                                  exc.errno or errno.EADDRINUSE) from None
            if addr.port == 0:
                port = srv.sockets[0].getsockname()[1]
                addr = Address("tcp", host=addr.host, port=port)
        self._servers.append(srv)
        self.listening.append(addr.url())
        log.info("listening on %s", addr)

    async def _listen_metrics(self, addr: Address) -> None:
        from ._metrics import serve_metrics

        try:
            srv = await asyncio.start_server(lambda r, w: serve_metrics(r, w, self.status),
                                             addr.host, addr.port)
        except OSError as exc:
            raise DaemonError(f"metrics {addr}: cannot listen: {exc.strerror}", str(addr),
                              exc.errno or errno.EADDRINUSE) from None
        port = srv.sockets[0].getsockname()[1]
        host = f"[{addr.host}]" if ":" in addr.host else addr.host
        self.metrics_url = f"http://{host}:{port}/metrics"
        self._servers.append(srv)
        log.info("metrics on %s", self.metrics_url)

    def stop(self) -> None:
        self._stopped.set()
        self._wake.set()

    async def wait_closed(self) -> None:
        await self._stopped.wait()
        await self.aclose()

    async def aclose(self) -> None:
        self._closing = True
        for srv in self._servers:
            srv.close()
        for s in list(self.sessions.values()):
            s.writer.transport.abort()
        if self._bus_task is not None:
            self._bus_task.cancel()
            try:
                await self._bus_task
            except (asyncio.CancelledError, Exception):
                pass
        self.close_now()

    def close_now(self) -> None:
        self._unwatch_late()
        for path in self._unix_paths:
            try:
                os.unlink(path)
            except OSError:
                pass
        self._unix_paths = []
        try:
            self.backend.close()
        finally:
            if self._lock:
                self._lock.release()
        self.port_state = "closed"

    # -- clients -----------------------------------------------------------------

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        peer = "?"
        s = Session(self, self._next_key, reader, writer, peer)
        self._next_key += 1
        if sock is not None and sock.family == socket.AF_UNIX:
            try:
                pid, uid, gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED,
                                                                    struct.calcsize("3i")))
                s.pid, s.uid, s.peer = pid, uid, f"unix pid {pid} uid {uid} gid {gid}"
            except OSError:
                s.peer = "unix"
        elif sock is not None:
            name = writer.get_extra_info("peername")
            s.peer = f"tcp {name[0]}:{name[1]}" if name else "tcp"
        log.info("client %d connected: %s", s.key, s.peer)
        if len(self.sessions) >= self.config.max_clients:
            self.counters["refused"] += 1
            s.send({"op": "refused", "error": _error_obj(DaemonError(
                f"too many clients ({self.config.max_clients})"))})
            writer.close()
            return
        self.sessions[s.key] = s
        try:
            await self._session(s)
        except (ProtocolError, asyncio.TimeoutError) as exc:
            why = str(exc) or "a message not finished in time"
            s.send({"op": "error", "error": _error_obj(ProtocolError(why))})
            s.cut(why)
        except (ConnectionError, OSError):
            pass
        finally:
            self._leave(s)

    def _leave(self, s: Session) -> None:
        self.sessions.pop(s.key, None)
        if s.joined:
            dropped = self.sched.remove(s.key)
            self.counters["dropped"] += len(dropped)
        s.closed = True
        if not s.writer.transport.is_closing():
            s.writer.close()
        log.info("client %d left", s.key)

    async def _session(self, s: Session) -> None:
        c = self.config
        messages = MessageReader(s.reader, c.body_timeout)
        hello = await messages.next(c.hello_timeout)
        if hello is None:
            return
        refusal = self._check_hello(s, hello)
        if refusal:
            self.counters["refused"] += 1
            log.warning("client %d (%s) refused: %s", s.key, s.peer, refusal)
            s.send({"op": "refused", "error": _error_obj(DaemonError(refusal))})
            await s.writer.drain()
            return
        self.sched.add(s.key, s.weight, s.priority, c.queue)
        s.joined = True
        s.send({"op": "welcome", "version": list(VERSION), "client": s.key, "protocol": c.protocol,
                "port": c.port, "baud": self.backend.baud, "weight": s.weight, "priority": s.priority,
                "timeout": c.timeout, "retries": c.retries, "pid": os.getpid(), "queue": c.queue,
                "port_state": self.port_state, **self.backend.info()})
        while not s.closed:
            msg = await messages.next()
            if msg is None:
                return
            self._request(s, msg)

    def _check_hello(self, s: Session, hello: Dict[str, Any]) -> Optional[str]:
        if hello.get("op") != "hello":
            return "the first message must be a hello"
        version = hello.get("version")
        if not (isinstance(version, list) and version and isinstance(version[0], int)):
            return "hello without a version [major, minor]"
        if version[0] != VERSION[0]:
            return (f"client protocol version {version[0]}.x, this daemon speaks "
                    f"{VERSION[0]}.{VERSION[1]} (major versions must match)")
        if self._token is not None:
            tok = hello.get("token")
            if not isinstance(tok, str) or not hmac.compare_digest(tok.encode(), self._token.encode()):
                return "bad or missing token (?token= or FAP_SERVE_TOKEN)"
        c = self.config
        w, p = hello.get("weight", 1), hello.get("priority", 0)
        if isinstance(w, bool) or not isinstance(w, int) or w < 1:
            return f"weight must be a whole number >= 1, not {w!r}"
        if isinstance(p, bool) or not isinstance(p, int) or p < 0:
            return f"priority must be a whole number >= 0, not {p!r}"
        s.weight, s.priority = min(w, c.max_weight), min(p, c.max_priority)
        name = hello.get("name")
        s.name = name[:64] if isinstance(name, str) else ""
        return None

    def _request(self, s: Session, msg: Dict[str, Any]) -> None:
        rid, op = msg.get("id"), msg.get("op")
        if not isinstance(op, str):
            raise ProtocolError("a request without an op")
        if op == "bye":
            s.writer.close()
            s.closed = True
            return
        try:
            if op == "status":
                s.send({"id": rid, "ok": True, "status": self.status()})
            elif op == "monitor":
                s.monitor = True
                self.backend.tapped = True
                s.send({"id": rid, "ok": True})
            elif op == "ping":
                s.send({"id": rid, "ok": True})
            elif op == "cancel":
                s.send({"id": rid, "ok": True, "cancelled": self._cancel(s, msg.get("of"))})
            elif op in self.backend.quick_ops:
                s.send({"id": rid, "ok": True, **self.backend.quick(op, msg)})
            else:
                job = self.backend.check(op, msg)
                try:
                    self.sched.push(s.key, Pending(s, rid, job, time.monotonic()))
                except ClientQueueFullError:
                    s.refused_full += 1
                    self.counters["queue_full"] += 1
                    raise
                s.in_flight += 1
                self._wake.set()
        except (ProtocolError, FapError) as exc:
            s.errors += 1
            s.send({"id": rid, "ok": False, "error": _error_obj(exc)})

    def _cancel(self, s: Session, of: Any) -> str:
        """A client gave up on its request ``of`` (an asyncio task cancelled): still queued,
        it leaves the queue; on the bus now, the transaction is ended as the engine ends a
        cancelled one (exec: a failure, the node's next message at SeqNo 0). Answers where
        it was: "queued", "running" or "none" (already answered, or not this client's)."""
        if not isinstance(of, int) or isinstance(of, bool):
            raise ProtocolError("cancel: field 'of' (the request id) must be an int")
        if self.sched.withdraw(s.key, lambda p: p.rid == of) is not None:
            s.in_flight -= 1
            self.counters["cancelled"] += 1
            return "queued"
        cur, task = self._current, self._running
        if cur is not None and cur.session is s and cur.rid == of and task is not None and not task.done():
            if self._cancelled is not cur:    # (cancelled once: a second cancel is the same)
                self._cancelled = cur
                task.cancel()
            return "running"
        return "none"

    # -- the bus -----------------------------------------------------------------

    async def _bus(self) -> None:
        loop = asyncio.get_running_loop()
        task = asyncio.current_task()
        out: Optional[Tuple[Session, Dict[str, Any]]] = None   # the last answer, not sent yet
        while True:
            item = self.sched.next()
            if item is None:
                if out is not None:
                    out[0].send(out[1])
                    out = None
                self._wake.clear()
                await self._wake.wait()
                continue
            if out is not None:
                # sent once this task first waits: the next request is on the wire by then
                # (run() writes it before its first wait), so the bus does not wait for
                # the last answer's JSON and socket write
                loop.call_soon(out[0].send, out[1])
                out = None
            key, pend = item
            s = pend.session
            answer: Dict[str, Any] = {"id": pend.rid}
            cancelled = False
            if self.port_state != "open":
                err: Optional[BaseException] = PortGoneError(
                    errno.ENODEV, f"{self.config.port}: device gone (the daemon reopens it)")
                cost = 0.0
            else:
                self._late_check()
                t0 = time.monotonic()
                err = None
                self._current = pend
                # awaited in this task (no task a transaction): a client's cancel cancels
                # this task while it waits inside run(), see _cancel
                self._running = task
                try:
                    answer.update(await self.backend.run(pend.job))
                except FapError as exc:
                    err = exc
                    answer.update(getattr(exc, "daemon_fields", {}))
                except asyncio.CancelledError:
                    if self._cancelled is not pend or self._closing:
                        raise
                    if task is not None and hasattr(task, "uncancel"):
                        task.uncancel()          # (3.11+: the cancel is handled here)
                    self.counters["cancelled"] += 1
                    cancelled = True
                except Exception as exc:     # a bug: say so to the client, keep the bus
                    log.exception("transaction failed")
                    err = DaemonError(f"internal error {type(exc).__name__}: {exc}", "", errno.EIO)
                finally:
                    self._current = self._running = self._cancelled = None
                cost = answer.pop("_cost", None) or time.monotonic() - t0
            self.sched.charge(key, cost)
            self.wire_time += cost
            self.counters["transactions"] += 1
            s.in_flight -= 1
            answer["wire_us"] = int(cost * 1e6)
            answer["queued_us"] = int((time.monotonic() - pend.queued) * 1e6 - cost * 1e6)
            late = answer.get("stats", {}).get(self.backend.LATE_COUNTER, 0)
            if late:                            # the client whose transaction timed out last
                owner = self._timed_out if self._timed_out is not None and not self._timed_out.closed else s
                self._count_late(owner, late)
            if cancelled:                       # its client is not waiting; counted apart
                answer.update(ok=False, error=_error_obj(DaemonError(
                    f"request {pend.rid} cancelled by its client", "", errno.ECANCELED)))
            elif err is not None:
                self.counters["errors"] += 1
                s.errors += 1
                answer.update(ok=False, error=_error_obj(err))
                if isinstance(err, FapTimeoutError):
                    self._timed_out = s
                    self._watch_late(s)
                if isinstance(err, PortGoneError) and self.port_state == "open":
                    self._port_gone(err)
            else:
                answer["ok"] = True
                s.replies += 1
            if s.closed:
                self.counters["dropped"] += 1   # its client left mid-transaction: nobody else gets it
            elif self.sched.pending():
                out = (s, answer)               # after the next request's write (above)
            else:
                s.send(answer)                  # nothing waits for the bus: at once
            # requests that came with the reply are read before the next turn is chosen (a
            # client whose next request is already here keeps its turn)
            await asyncio.sleep(0)

    # late replies: bytes that arrive after a transaction timed out, before the next begins

    def _watch_late(self, s: Session) -> None:
        self._unwatch_late()
        try:
            fd = self.backend.fd()
        except FapError:
            return
        if fd < 0:
            return
        self.backend.release_fd()
        self._late_owner, self._late_fd = s, fd
        asyncio.get_running_loop().add_reader(fd, self._late_seen)

    def _unwatch_late(self) -> None:
        if self._late_fd >= 0:
            try:
                asyncio.get_event_loop().remove_reader(self._late_fd)
            except (RuntimeError, ValueError, OSError):
                pass
        self._late_fd = -1

    def _late_seen(self) -> None:
        owner = self._late_owner
        self._unwatch_late()
        self._late_owner = None
        if owner is not None:
            self._count_late(owner, 1)
        try:
            self.backend.flush()
        except FapError:
            pass

    def _late_check(self) -> None:
        """Before a transaction: a late reply already waiting is counted and dropped."""
        if self._late_fd < 0:
            return
        fd = self._late_fd
        self._unwatch_late()
        ready, _, _ = select.select([fd], [], [], 0)
        if ready:
            self._late_fd = fd
            self._late_seen()
        self._late_owner = None

    def _count_late(self, s: Session, n: int) -> None:
        s.late += n
        self.counters["late"] += n
        log.info("client %d: %d late repl%s (after its timeout; delivered to nobody)",
                 s.key, n, "y" if n == 1 else "ies")

    # device gone: tell everyone, reopen in the background

    def _port_gone(self, err: BaseException) -> None:
        self._unwatch_late()
        self._mark_gone(f"{err}; reopening every {self.config.reopen_interval:.1f} s")
        asyncio.get_running_loop().create_task(self._reopen())

    def _mark_gone(self, why: str) -> None:
        """The port's state, counter, log line and client event when the device vanished."""
        self.port_state = "gone"
        self.counters["port_gone"] += 1
        log.warning("%s: %s", self.config.port, why)
        self._broadcast_event({"event": "port_gone", "message": f"{self.config.port}: device gone"})

    def _engine_port(self, back: bool) -> None:
        """An engine that reopens its own port (FAP) lost it or has it back: the same
        state, counters and client events as the daemon's own reopen."""
        if not back and self.port_state == "open":
            self._mark_gone("device gone; the engine reopens it")
        elif back and self.port_state == "gone":
            self._port_back()

    def _port_back(self) -> None:
        self.port_state = "open"
        self.counters["reopens"] += 1
        log.warning("%s: device back", self.config.port)
        self._broadcast_event({"event": "port_back", "message": f"{self.config.port}: device back"})

    async def _reopen(self) -> None:
        told = False
        while not self._stopped.is_set():
            await asyncio.sleep(self.config.reopen_interval)
            try:
                self.backend.reopen()
            except FapError as exc:
                log.debug("reopen: %s", exc)
                continue
            except Exception:               # a defect, not the device: say it once, keep trying
                if not told:
                    log.exception("%s: reopen failed", self.config.port)
                    told = True
                continue
            self._port_back()
            return

    def _broadcast_event(self, obj: Dict[str, Any]) -> None:
        for s in list(self.sessions.values()):
            if s.joined:
                s.send(obj)

    def _frame(self, direction: str, status: str, t_ns: int, data: bytes) -> None:
        """Every frame the engine sends or receives: to the monitor taps."""
        taps = [s for s in self.sessions.values() if s.monitor and not s.closed]
        if not taps:
            self.backend.tapped = False
            return
        ev = {"event": "frame", "dir": direction, "status": status, "t_ns": t_ns,
              "t": time.time(), "data": data.hex()}
        for s in taps:
            s.send(ev)

    # -- status ------------------------------------------------------------------

    def status(self) -> Dict[str, Any]:
        c = self.config
        try:
            engine = self.backend.counters()
        except FapError:
            engine = {}
        return {"daemon": {"pid": os.getpid(), "protocol": c.protocol, "port": c.port,
                           "baud": self.backend.baud, "port_state": self.port_state,
                           "listen": self.listening, "version": list(VERSION),
                           "uptime_s": round(time.time() - self.started, 1),
                           "wire_time": round(self.wire_time, 6)},
                "totals": dict(self.counters, clients=len(self.sessions),
                               queued=self.sched.pending()),
                "clients": [s.status(self.wire_time) for s in self.sessions.values() if s.joined],
                "engine": engine}


def run(config: ServeConfig, *, ready: Any = None) -> int:
    """Run a daemon until SIGTERM / SIGINT. ``ready(daemon)`` is called once it listens."""
    if not isinstance(config, ServeConfig):
        raise InvalidTypeError(f"config must be a ServeConfig, not {type(config).__name__}")
    if ready is not None and not callable(ready):
        raise InvalidTypeError("ready must be callable or None")
    config.check()
    async def main() -> None:
        d = Daemon(config)
        await d.start()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, d.stop)
        if ready is not None:
            ready(d)
        await d.wait_closed()

    asyncio.run(main())
    return 0
