"""Helpers of the ``fap web`` tests: a sim site, a master that polls it, an SSE reader."""
from __future__ import annotations

import http.client
import json
import os
import shutil
import threading
import time
import urllib.error
import urllib.request
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple

import pytest

#: bounded waits of the tests, seconds
WAIT_S = float(os.environ.get("FAP_TEST_WAIT", "15"))

SITE = {
    "sim": {"seed": 1},
    "bus": [{"name": "field", "protocol": "exec", "baud": 115200,
             "node": [{"range": [1, 3]}, {"address": 5, "answer": "table",
                                          "table": [{"request": "01*", "reply": "aa55"}],
                                          "default": "ff"}]}],
}
NODES = (1, 2, 3, 5)


def need_tool(name: str) -> str:
    """Path of an external tool; skip without it unless CI is set (then fail)."""
    path = shutil.which(name)
    if path:
        return path
    if os.environ.get("CI"):
        pytest.fail(f"{name} is required when CI is set")
    pytest.skip(f"{name} not installed")
    raise AssertionError("unreachable")


def get(url: str, headers: Optional[Dict[str, str]] = None) -> Tuple[int, bytes]:
    req = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=WAIT_S) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def get_json(url: str, headers: Optional[Dict[str, str]] = None) -> Any:
    status, body = get(url, headers)
    assert status == 200, (status, body[:300])
    return json.loads(body)


def send(url: str, method: str, body: bytes = b"", content_type: str = "application/json",
         headers: Optional[Dict[str, str]] = None) -> Tuple[int, Any]:
    req = urllib.request.Request(url, data=body if method != "DELETE" else None, method=method,
                                 headers={"Content-Type": content_type, **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=WAIT_S) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def wait_until(cond: Callable[[], Any], timeout: float = WAIT_S, what: str = "condition") -> Any:
    """Poll ``cond`` (bounded) until it is true; its value."""
    deadline = time.monotonic() + timeout
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


def node_rows(url: str) -> Dict[str, Dict[str, Any]]:
    return {n["node"]: n for n in get_json(url + "api/stats")["nodes"]}


class Poller:
    """A real exec async master (the C engine) polling the sim's nodes in a thread. Its
    timeout is generous: a late reply (a loaded machine) would collide with the next request."""

    def __init__(self, port: str, nodes=NODES, timeout: float = 0.3) -> None:
        from fap_py import execasync

        self.master = execasync.Master(port, 115200, timeout=timeout, retries=0)
        self.nodes = nodes
        self.rounds = 0
        self.errors: Dict[int, int] = dict.fromkeys(nodes, 0)
        self._stop = threading.Event()
        self._idle = threading.Event()
        self._go = threading.Event()
        self._go.set()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from fap_py.errors import FapError

        while not self._stop.is_set():
            if not self._go.is_set():
                self._idle.set()
                self._go.wait(0.1)
                continue
            self._idle.clear()
            for n in self.nodes:
                try:
                    self.master.transact(n, b"\x01\x02")
                except FapError:
                    self.errors[n] += 1
            self.rounds += 1

    def pause(self) -> None:
        """Stop polling after the current round (returns once the master is idle)."""
        self._go.clear()
        assert self._idle.wait(WAIT_S)

    def resume(self) -> None:
        self._go.set()

    def close(self) -> None:
        self._stop.set()
        self._go.set()
        self._thread.join(WAIT_S)
        self.master.close()


class SSE:
    """A Server-Sent Events reader over http.client (bounded by a socket timeout)."""

    def __init__(self, host: str, port: int, path: str, headers: Optional[Dict[str, str]] = None) -> None:
        self.conn = http.client.HTTPConnection(host, port, timeout=WAIT_S)
        self.conn.request("GET", path, headers=headers or {})
        self.resp = self.conn.getresponse()
        assert self.resp.status == 200, self.resp.status

    def events(self) -> Iterator[Tuple[str, Any]]:
        event, data = "message", []
        while True:
            line = self.resp.readline()
            if not line:
                return
            line = line.rstrip(b"\r\n")
            if not line:
                if data:
                    yield event, json.loads(b"\n".join(data))
                event, data = "message", []
            elif line.startswith(b"event: "):
                event = line[7:].decode()
            elif line.startswith(b"data: "):
                data.append(line[6:])

    def close(self) -> None:
        self.conn.close()


def frames_of(events: List[Tuple[str, Any]]) -> List[Dict[str, Any]]:
    return [f for kind, d in events if kind == "frames" for f in d]
