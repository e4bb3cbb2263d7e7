"""A client's connection to a daemon (docs/daemon.md). Private.

:class:`Connection` is the blocking form: any number of threads call
:meth:`Connection.call` at once, each gets its own answer (matched by ``id``;
a reader thread hands them out). :class:`AsyncConnection` is the asyncio
form: one reader task, a future per request, no thread. Both say hello
first (version, token, weight, priority) and turn an error the daemon sends
back into the same exception class a direct open would raise.
"""
from __future__ import annotations

import asyncio
import errno
import itertools
import logging
import os
import socket
import threading
from typing import Any, Callable, Dict, Mapping, Optional, Type

from .. import errors as _errors
from .._validate import check_timeout
from ._errors import (
    BadUrlError,
    ClientQueueFullError,
    DaemonError,
    DaemonGoneError,
    DaemonRefusedError,
    ProtocolError,
)
from ._url import Address, ClientUrl, parse_client_url, query_int
from ._wire import HEADER_SIZE, VERSION, MessageReader, body_size, pack, unpack

log = logging.getLogger("fap_py.serve.client")

#: how long a client waits for the daemon's answer unless told (?timeout=S)
DEFAULT_ANSWER_TIMEOUT = 60.0
#: the environment variable that holds the token when the URL has none
TOKEN_ENV = "FAP_SERVE_TOKEN"

_LOCAL = {c.__name__: c for c in (ClientQueueFullError, DaemonError, DaemonGoneError,
                                  DaemonRefusedError, ProtocolError, BadUrlError)}


def _package_classes() -> Dict[str, Type[BaseException]]:
    out: Dict[str, Type[BaseException]] = {n: c for n, c in vars(_errors).items()
           if isinstance(c, type) and issubclass(c, _errors.FapError)}
    out.update(_LOCAL)
    return out


def error_from_wire(err: Any, url: str, extra: Optional[Mapping[str, Callable[..., BaseException]]] = None
                    ) -> BaseException:
    """The exception for an ``error`` object the daemon sent: the class it names
    (``extra`` first: a protocol's own classes), else DaemonError."""
    if not isinstance(err, dict):
        return ProtocolError(f"bad error object {err!r:.80}", url)
    name, text = str(err.get("type", "")), str(err.get("message", ""))
    code = err.get("errno")
    if extra and name in extra:
        return extra[name](err)
    cls = _package_classes().get(name)
    if cls is None:
        return DaemonError(f"daemon error {name}: {text}", url, errno.EIO)
    if issubclass(cls, (DaemonError,)):
        return cls(text, url) if cls is not DaemonError else DaemonError(text, url)
    if issubclass(cls, _errors.PortError):
        return cls(int(code) if isinstance(code, int) else errno.EIO, text)
    return cls(text)


def _settings(url: ClientUrl, weight: Optional[int], priority: Optional[int],
              token: Optional[str], name: Optional[str]) -> Dict[str, Any]:
    q = url.query
    w = weight if weight is not None else query_int(q, "weight", None, url.text)
    p = priority if priority is not None else query_int(q, "priority", None, url.text)
    for what, v in (("weight", w), ("priority", p)):
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < (1 if what == "weight" else 0)):
            raise BadUrlError(f"{url.text}: {what} must be a whole number >= "
                              f"{1 if what == 'weight' else 0}, not {v!r}", url.text)
    tok = token if token is not None else q.get("token") or os.environ.get(TOKEN_ENV) or None
    if tok is not None and not isinstance(tok, str):
        raise BadUrlError(f"token must be a str, not {type(tok).__name__}", url.text)
    hello: Dict[str, Any] = {"op": "hello", "version": list(VERSION), "pid": os.getpid(),
                             "name": q.get("name") or name or ""}   # the URL's name=, else the caller's
    if w is not None:
        hello["weight"] = w
    if p is not None:
        hello["priority"] = p
    if tok:
        hello["token"] = tok
    return hello


def _check_opt_str(value: Any, what: str) -> Optional[str]:
    if value is not None and not isinstance(value, str):
        raise _errors.InvalidTypeError(f"{what} must be a str or None, not {type(value).__name__}")
    return value


def _check_errors(value: Any) -> Dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping) or not all(isinstance(k, str) and callable(v) for k, v in value.items()):
        raise _errors.InvalidTypeError("errors must map exception names to factories")
    return dict(value)


def _request(op: Any, rid: int, fields: Dict[str, Any]) -> bytes:
    if not isinstance(op, str) or not op:
        raise _errors.InvalidTypeError(f"op must be a non-empty str, not {op!r:.40}")
    try:
        return pack({"op": op, "id": rid, **fields})
    except (TypeError, ValueError) as exc:
        raise _errors.InvalidTypeError(f"request fields must be JSON values: {exc}") from None


def _answer_timeout(url: ClientUrl) -> float:
    text = url.query.get("timeout")
    if text is None:
        return DEFAULT_ANSWER_TIMEOUT
    try:
        t = float(text)
    except ValueError:
        t = -1.0
    if not 0 < t <= 86400:
        raise BadUrlError(f"{url.text}: timeout must be seconds in (0, 86400], not {text!r}", url.text)
    return t


def _hello(url: Any, protocol: Optional[str], weight: Optional[int], priority: Optional[int],
           token: Optional[str], name: Optional[str], errors: Optional[Mapping[str, Any]]
           ) -> "tuple[Dict[str, Any], ClientUrl, float, Dict[str, Any]]":
    """What both connection forms check and build before they connect: the error
    classes, the parsed URL, the answer timeout and the hello message."""
    checked = _check_errors(errors)
    _check_opt_str(protocol, "protocol")
    _check_opt_str(name, "name")
    parsed = parse_client_url(url)
    return checked, parsed, _answer_timeout(parsed), _settings(parsed, weight, priority, token, name)


def _no_daemon(url: str, exc: OSError) -> DaemonError:
    return DaemonError(f"no daemon at {url}: {exc.strerror or exc} (is `fap serve` running?)",
                       "", exc.errno or errno.ECONNREFUSED)


def _check_welcome(msg: Optional[Dict[str, Any]], url: str, protocol: Optional[str]) -> Dict[str, Any]:
    if msg is None:
        raise DaemonGoneError(f"{url}: the daemon closed the connection before its welcome")
    if msg.get("op") == "refused":
        err = msg.get("error") or {}
        raise DaemonRefusedError(f"{url}: refused by the daemon: {err.get('message', '?')}")
    if msg.get("op") != "welcome":
        raise ProtocolError(f"{url}: expected a welcome, got {str(msg)[:80]}")
    if protocol is not None and msg.get("protocol") != protocol:
        raise DaemonRefusedError(f"{url}: the daemon runs protocol {msg.get('protocol')!r}, "
                                 f"not {protocol!r}")
    return msg


def _connect_socket(addr: Address, url: str, timeout: float) -> socket.socket:
    try:
        if addr.kind == "unix":
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
            s.settimeout(timeout)
            try:
                s.connect(addr.path)
            except BaseException:
                s.close()
                raise
        else:
            s = socket.create_connection((addr.host, addr.port), timeout=timeout)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    except OSError as exc:
        raise _no_daemon(url, exc) from None
    return s


class Connection:
    """A blocking connection to the daemon at ``url`` (``fapd:///path`` or ``fapd://host:port``).

    ``protocol``: refuse a daemon that runs another protocol. ``weight``,
    ``priority``, ``token``, ``name`` override the URL's query (the token also
    comes from ``$FAP_SERVE_TOKEN``). Raises :class:`DaemonError` (no daemon),
    :class:`DaemonRefusedError` (token, version, protocol, too many clients).
    """

    def __init__(self, url: Any, *, protocol: Optional[str] = None, weight: Optional[int] = None,
                 priority: Optional[int] = None, token: Optional[str] = None,
                 name: Optional[str] = None, errors: Optional[Mapping[str, Any]] = None) -> None:
        self._sock: Optional[socket.socket] = None
        self.errors, parsed, self.timeout, hello = _hello(url, protocol, weight, priority, token,
                                                          name, errors)
        self.url = parsed.text
        self._ids = itertools.count(1)
        self._wlock = threading.Lock()
        self._waiting: Dict[int, list] = {}
        self._wait_lock = threading.Lock()
        self._events: list = []
        self._event_cond = threading.Condition()
        self._dead: Optional[BaseException] = None
        self._sock = _connect_socket(parsed.address, self.url, min(self.timeout, 10.0))
        self._rfile = self._sock.makefile("rb")
        self._sock.sendall(pack(hello))
        try:
            self.welcome = _check_welcome(self._read(), self.url, protocol)
        except BaseException:
            self.close()
            raise
        self._sock.settimeout(None)
        self._reader = threading.Thread(target=self._read_loop, name=f"fapd {self.url}", daemon=True)
        self._reader.start()

    # -- reading ---------------------------------------------------------------

    def _read(self) -> Optional[Dict[str, Any]]:
        try:
            head = self._rfile.read(HEADER_SIZE)
        except socket.timeout:
            raise DaemonGoneError(f"{self.url}: no answer from the daemon") from None
        except OSError:
            return None
        if len(head) < HEADER_SIZE:
            return None
        n = body_size(head)
        body = self._rfile.read(n)
        if len(body) < n:
            return None
        return unpack(body)

    def _read_loop(self) -> None:
        why: BaseException = DaemonGoneError(f"{self.url}: the daemon closed the connection")
        try:
            while True:
                msg = self._read()
                if msg is None:
                    break
                rid = msg.get("id")
                if rid is None or "event" in msg:   # an event is never an answer (docs/daemon.md)
                    self._event(msg)
                    continue
                with self._wait_lock:
                    slot = self._waiting.pop(rid, None)
                if slot is not None:
                    slot[1] = msg
                    slot[0].set()
        except (ProtocolError, ValueError) as exc:
            why = exc
        self._dead = why
        with self._wait_lock:
            slots, self._waiting = list(self._waiting.values()), {}
        for slot in slots:
            slot[0].set()
        with self._event_cond:
            self._event_cond.notify_all()

    def _event(self, msg: Dict[str, Any]) -> None:
        ev = msg.get("event")
        if ev in ("port_gone", "port_back"):
            log.warning("%s: %s", self.url, msg.get("message", ev))
        with self._event_cond:
            self._events.append(msg)
            if len(self._events) > 10000:       # nobody reads them: keep the newest
                del self._events[:5000]
            self._event_cond.notify_all()

    def next_event(self, timeout: Optional[float]) -> Optional[Dict[str, Any]]:
        """The next message the daemon sent without an id (monitor frames, port events);
        None when ``timeout`` passed. Raises DaemonGoneError once the daemon is gone."""
        timeout = check_timeout(timeout)
        with self._event_cond:
            if not self._events and self._dead is None:
                self._event_cond.wait(timeout)
            if self._events:
                return self._events.pop(0)
            if self._dead is not None:
                raise DaemonGoneError(f"{self.url}: the daemon closed the connection")
            return None

    # -- requests ----------------------------------------------------------------

    def call(self, op: str, extra_errors: Optional[Mapping[str, Callable[..., BaseException]]] = None,
             **fields: Any) -> Dict[str, Any]:
        """Send one request and wait for its answer; raise the error it carries."""
        extra = _check_errors(extra_errors)
        return self.submit(op, **fields).result(extra or None)

    def submit(self, op: str, **fields: Any) -> "Answer":
        """Send one request without waiting: its :class:`Answer` waits when asked."""
        if self._sock is None:
            raise _errors.ClosedError(f"connection to {self.url} closed")
        if self._dead is not None:
            raise DaemonGoneError(f"{self.url}: the daemon closed the connection")
        rid = next(self._ids)
        data = _request(op, rid, fields)
        slot: list = [threading.Event(), None]
        with self._wait_lock:
            self._waiting[rid] = slot
        try:
            with self._wlock:
                self._sock.sendall(data)
        except OSError:
            with self._wait_lock:
                self._waiting.pop(rid, None)
            raise DaemonGoneError(f"{self.url}: the daemon closed the connection") from None
        return Answer(self, rid, slot)

    def close(self) -> None:
        s, self._sock = self._sock, None
        if s is None:
            return
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        s.close()
        reader = getattr(self, "_reader", None)
        if reader is not None and reader is not threading.current_thread():
            reader.join(2.0)

    def __enter__(self) -> "Connection":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Answer:
    """The answer to one submitted request (:meth:`Connection.submit`)."""

    def __init__(self, conn: Connection, rid: int, slot: list) -> None:
        self._conn, self._rid, self._slot = conn, rid, slot

    def result(self, extra_errors: Optional[Mapping[str, Callable[..., BaseException]]] = None,
               timeout: Optional[float] = None) -> Dict[str, Any]:
        """Wait for it (at most ``timeout``, default the connection's answer timeout);
        the answer, or the error it carries raised."""
        extra_errors = _check_errors(extra_errors) or None
        timeout = check_timeout(timeout)
        c = self._conn
        if not self._slot[0].wait(c.timeout if timeout is None else timeout):
            with c._wait_lock:
                c._waiting.pop(self._rid, None)
            raise DaemonGoneError(f"{c.url}: no answer from the daemon within {c.timeout} s")
        msg = self._slot[1]
        if msg is None:
            raise DaemonGoneError(f"{c.url}: the daemon closed the connection")
        return _result(msg, c.url, extra_errors or c.errors)


def _result(msg: Dict[str, Any], url: str,
            extra: Optional[Mapping[str, Callable[..., BaseException]]]) -> Dict[str, Any]:
    if msg.get("ok"):
        return msg
    err = error_from_wire(msg.get("error"), url, extra)
    err.daemon_answer = msg  # type: ignore[attr-defined]   # what came with the error (stats deltas)
    raise err


class _NoAnswer(Exception):
    """The answer timeout ran out (AsyncConnection.call turns it into DaemonGoneError)."""


def _no_answer(fut: "asyncio.Future[Any]") -> None:
    if not fut.done():
        fut.set_exception(_NoAnswer())


class AsyncConnection:
    """The asyncio form of :class:`Connection`: ``await AsyncConnection.open(url, ...)``;
    each :meth:`call` awaits its own answer (a future matched by id; one reader task)."""

    def __init__(self) -> None:
        self.url = ""
        self.timeout = DEFAULT_ANSWER_TIMEOUT
        self._writer: Optional[asyncio.StreamWriter] = None
        self._futures: Dict[int, "asyncio.Future[Dict[str, Any]]"] = {}
        self._ids = itertools.count(1)
        self._task: Optional["asyncio.Task[None]"] = None
        self._dead = False
        self.errors: Dict[str, Any] = {}
        self.welcome: Dict[str, Any] = {}

    @classmethod
    async def open(cls, url: Any, *, protocol: Optional[str] = None, weight: Optional[int] = None,
                   priority: Optional[int] = None, token: Optional[str] = None,
                   name: Optional[str] = None, errors: Optional[Mapping[str, Any]] = None
                   ) -> "AsyncConnection":
        self = cls()
        self.errors, parsed, self.timeout, hello = _hello(url, protocol, weight, priority, token,
                                                          name, errors)
        self.url = parsed.text
        addr = parsed.address
        try:
            if addr.kind == "unix":
                reader, writer = await asyncio.open_unix_connection(addr.path)
            else:
                reader, writer = await asyncio.open_connection(addr.host, addr.port)
        except OSError as exc:
            raise _no_daemon(self.url, exc) from None
        self._writer = writer
        writer.write(pack(hello))
        messages = MessageReader(reader, 10.0)   # the welcome and all after it: one reader
        try:
            msg = await messages.next(first_timeout=min(self.timeout, 10.0))   # not wait_for (_wire.py)
            self.welcome = _check_welcome(msg, self.url, protocol)
        except BaseException:
            writer.close()
            raise
        self._task = asyncio.get_running_loop().create_task(self._read_loop(messages))
        return self

    async def _read_loop(self, messages: MessageReader) -> None:
        try:
            while True:
                msg = await messages.next()
                if msg is None:
                    break
                rid = msg.get("id")
                fut = self._futures.pop(rid, None) if isinstance(rid, int) and "event" not in msg else None
                if fut is not None and not fut.done():
                    fut.set_result(msg)
        except (ProtocolError, asyncio.TimeoutError, OSError):
            pass
        finally:
            self._dead = True
            for fut in self._futures.values():
                if not fut.done():   # closed by us (close() from another task): ClosedError
                    fut.set_exception(_errors.ClosedError(f"connection to {self.url} closed")
                                      if self._writer is None else
                                      DaemonGoneError(f"{self.url}: the daemon closed the connection"))
            self._futures.clear()

    async def call(self, op: str, extra_errors: Optional[Mapping[str, Callable[..., BaseException]]] = None,
                   **fields: Any) -> Dict[str, Any]:
        if self._writer is None:
            raise _errors.ClosedError(f"connection to {self.url} closed")
        if self._dead:
            raise DaemonGoneError(f"{self.url}: the daemon closed the connection")
        rid = next(self._ids)
        data = _request(op, rid, fields)
        loop = asyncio.get_running_loop()
        fut: "asyncio.Future[Dict[str, Any]]" = loop.create_future()
        self._futures[rid] = fut
        self._writer.write(data)
        # a timer, not wait_for: the same deadline without a second future and its callbacks
        timer = loop.call_later(self.timeout, _no_answer, fut)
        try:
            msg = await fut
        except _NoAnswer:
            raise DaemonGoneError(f"{self.url}: no answer from the daemon within {self.timeout} s") from None
        except asyncio.CancelledError:
            # the task gave up: the daemon drops the request from its queue, or ends the
            # transaction on the bus as a cancelled direct one ends (its answer is not awaited)
            if self._writer is not None and not self._dead:
                self._writer.write(_request("cancel", next(self._ids), {"of": rid}))
            raise
        finally:
            timer.cancel()
            self._futures.pop(rid, None)
        return _result(msg, self.url, extra_errors or self.errors)

    def abandon(self) -> None:
        """Drop the connection without its loop (that loop may be closed already)."""
        w, self._writer = self._writer, None
        if w is not None:
            try:
                w.transport.abort()
            except (RuntimeError, OSError):
                pass

    async def close(self) -> None:
        w, self._writer = self._writer, None
        if w is None:
            return
        w.close()
        try:
            await w.wait_closed()
        except OSError:
            pass
        if self._task is not None:
            self._task.cancel()
            try:
                await self._task
            except (asyncio.CancelledError, Exception):
                pass


class PerLoop:
    """One :class:`AsyncConnection` per event loop (``asyncio.run`` twice makes two loops;
    a connection lives in the loop that opened it). ``await get()`` opens it once, the
    tasks that ask meanwhile wait for the same one."""

    def __init__(self, url: str, **kw: Any) -> None:
        self._url, self._kw = url, kw
        self._conn: Optional[AsyncConnection] = None
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._opening: Optional["asyncio.Task[AsyncConnection]"] = None

    async def get(self) -> AsyncConnection:
        loop = asyncio.get_running_loop()
        if self._conn is not None and self._loop is loop and not self._conn._dead:
            return self._conn
        if self._opening is None or self._opening.get_loop() is not loop:
            self._opening = loop.create_task(AsyncConnection.open(self._url, **self._kw))
        opening = self._opening
        try:
            conn = await asyncio.shield(opening)
        finally:
            if opening.done() and self._opening is opening:
                self._opening = None
        if self._conn is not conn:
            old, self._conn, self._loop = self._conn, conn, loop
            if old is not None:
                old.abandon()
        return conn

    async def close(self) -> None:
        conn, self._conn = self._conn, None
        if conn is None:
            return
        try:
            same = self._loop is asyncio.get_running_loop()
        except RuntimeError:
            same = False
        if same:
            await conn.close()
        else:
            conn.abandon()

    def abandon(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            conn.abandon()
