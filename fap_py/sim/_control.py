"""The control socket of a running sim: JSON lines in and out (docs/sim.md, "Control protocol").

``--control unix:PATH`` makes a Unix stream socket at PATH. Each request is one JSON object on
one line; each answer is one JSON object on one line, ``{"ok": true, ...}`` or
``{"ok": false, "error": "..."}``. Requests::

    {"cmd": "status"}
    {"cmd": "fault.list"}
    {"cmd": "fault.add", "kind": "late_reply", "node": 5, "bus": "field", "probability": 0.5, "ms": 300}
    {"cmd": "fault.remove", "id": 3}            (or "id": "all")

A line that is not JSON, not an object, an unknown command or a bad argument gets an error
answer and the connection stays open; a line longer than :data:`MAX_LINE` bytes gets an error
answer and the connection is closed. Nothing a client sends stops the sim.
"""
from __future__ import annotations

import json
import logging
import os
import select
import socket
import stat
import threading
from typing import Any, Dict, List

from ..errors import FapError, FileError, InvalidValueError
from ._faults import FAULT_KEYS, fault_keywords

log = logging.getLogger("fap_py.sim")

MAX_LINE = 64 * 1024
MAX_CLIENTS = 16
_FAULT_KEYS = {"kind", *FAULT_KEYS}


class ControlError(InvalidValueError):
    """A bad control address or a refused request."""


def unix_path(spec: str) -> str:
    """``unix:PATH`` -> PATH."""
    if not isinstance(spec, str) or not spec.startswith("unix:") or len(spec) <= 5:
        raise ControlError(f"--control takes unix:PATH, not {spec!r}")
    path = spec[5:]
    if "\0" in path or len(os.fsencode(path)) > 107:
        raise ControlError(f"bad control socket path {path!r} (at most 107 bytes)")
    return path


def handle(sim: Any, line: bytes) -> Dict[str, Any]:
    """One request line -> its answer (never raises)."""
    try:
        req = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return {"ok": False, "error": "not a JSON line"}
    if not isinstance(req, dict):
        return {"ok": False, "error": "a request is a JSON object"}
    cmd = req.get("cmd")
    try:
        if cmd == "status":
            return {"ok": True, **sim.status()}
        if cmd == "fault.list":
            return {"ok": True, "faults": sim.faults.list()}
        if cmd == "fault.add":
            extra = set(req) - _FAULT_KEYS - {"cmd"}
            if extra:
                return {"ok": False, "error": f"unknown key(s) {', '.join(sorted(extra))} "
                        f"(known: {', '.join(sorted(_FAULT_KEYS))})"}
            if "kind" not in req:
                return {"ok": False, "error": "fault.add needs 'kind'"}
            return {"ok": True, "fault": sim.add_fault(req["kind"], **fault_keywords(req))}
        if cmd == "fault.remove":
            if "id" not in req:
                return {"ok": False, "error": "fault.remove needs 'id' (a fault id or \"all\")"}
            gone = sim.faults.remove(req["id"])
            return {"ok": True, "removed": [f.public() for f in gone]}
    except FapError as exc:
        return {"ok": False, "error": str(exc)}
    except Exception as exc:   # a bug must not stop the sim: say so
        log.exception("control request failed")
        return {"ok": False, "error": f"internal error {type(exc).__name__}: {exc}"}
    return {"ok": False, "error": f"unknown cmd {cmd!r} (status, fault.list, fault.add, fault.remove)"}


class ControlServer:
    """Serves :func:`handle` on a Unix socket in a thread; a context manager."""

    def __init__(self, sim: Any, spec: str) -> None:
        self.sim = sim
        self.path = unix_path(spec)
        try:
            st = os.lstat(self.path)
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise FileError(exc.errno or 5, f"control socket: {exc.strerror}", self.path) from None
        else:
            if not stat.S_ISSOCK(st.st_mode):
                raise FileError(17, "control socket: exists and is not a socket", self.path)
            if _alive(self.path):
                raise FileError(98, "control socket: another sim answers there", self.path)
            os.unlink(self.path)
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self._sock.bind(self.path)
            os.chmod(self.path, 0o600)
            self._sock.listen(8)
        except OSError as exc:
            self._sock.close()
            raise FileError(exc.errno or 5, f"control socket: {exc.strerror}", self.path) from None
        self._stop_r, self._stop_w = os.pipe()
        self._clients: List[threading.Thread] = []
        self._open = 0
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._accept, name="fap-sim control", daemon=True)
        self._thread.start()
        self.refused = 0

    def _accept(self) -> None:
        while True:
            r, _, _ = select.select([self._sock.fileno(), self._stop_r], [], [])
            if self._stop_r in r:
                return
            try:
                conn, _ = self._sock.accept()
            except OSError:
                continue
            with self._lock:
                if self._open >= MAX_CLIENTS:
                    self.refused += 1
                    _send(conn, {"ok": False, "error": "too many control clients"})
                    conn.close()
                    continue
                self._open += 1
            t = threading.Thread(target=self._client, args=(conn,), daemon=True, name="fap-sim client")
            t.start()

    def _client(self, conn: socket.socket) -> None:
        buf = b""
        try:
            while True:
                r, _, _ = select.select([conn.fileno(), self._stop_r], [], [])
                if self._stop_r in r:
                    return
                data = conn.recv(65536)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    if len(line) > MAX_LINE:
                        _send(conn, {"ok": False, "error": f"line longer than {MAX_LINE} bytes"})
                        return
                    if line.strip():
                        _send(conn, handle(self.sim, line))
                if len(buf) > MAX_LINE:
                    self.refused += 1
                    _send(conn, {"ok": False, "error": f"line longer than {MAX_LINE} bytes"})
                    return
        except OSError:
            return
        finally:
            conn.close()
            with self._lock:
                self._open -= 1

    def close(self) -> None:
        if self._stop_w < 0:
            return
        os.write(self._stop_w, b"x")
        self._thread.join(5.0)
        self._sock.close()
        try:
            os.unlink(self.path)
        except OSError:
            pass
        os.close(self._stop_w)
        self._stop_w = -1

    def __enter__(self) -> "ControlServer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _send(conn: socket.socket, obj: Dict[str, Any]) -> None:
    try:
        conn.sendall(json.dumps(obj, separators=(",", ":")).encode() + b"\n")
    except OSError:
        pass


def _alive(path: str) -> bool:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.connect(path)
        return True
    except OSError:
        return False
    finally:
        s.close()


def request(spec: str, obj: Dict[str, Any], timeout: float = 5.0) -> Dict[str, Any]:
    """Send one request to the sim at ``spec`` (``unix:PATH``); its answer."""
    path = unix_path(spec)
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout)
    try:
        try:
            s.connect(path)
        except OSError as exc:
            raise FileError(exc.errno or 2, f"control socket: {exc.strerror} (is `fap sim "
                            f"--control unix:{path}` running?)", path) from None
        s.sendall(json.dumps(obj).encode() + b"\n")
        buf = b""
        while b"\n" not in buf:
            data = s.recv(65536)
            if not data:
                raise ControlError(f"{path}: the sim closed the connection without an answer")
            buf += data
            if len(buf) > 16 * MAX_LINE * 16:
                raise ControlError(f"{path}: answer too long")
        return dict(json.loads(buf.split(b"\n", 1)[0]))
    except socket.timeout:
        raise ControlError(f"{path}: no answer within {timeout} s") from None
    finally:
        s.close()


def counters(spec: str, timeout: float = 1.0) -> Dict[str, Any]:
    """The running sim's counters, for a tool that runs beside it (``fap monitor
    --sim-control``, the bridge's ``[metrics] sim_control``): its ``status`` answer without
    ``ok``. FileError when nothing answers at ``spec``, ControlError for a refusal or no
    answer within ``timeout`` seconds."""
    ans = request(spec, {"cmd": "status"}, timeout)
    if not ans.pop("ok", False):
        raise ControlError(f"{unix_path(spec)}: the sim refused status: {ans.get('error')}")
    return ans
