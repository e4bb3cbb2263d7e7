"""Issue 32 item 14: a connect timeout is a port error (PortError, exit 3) for every API
and command, as docs/port.md's error table and docs/cli.md say, not a "timed out" or
"no reply" (FapTimeoutError / NoReplyError, exit 1)."""
from __future__ import annotations

import errno
import socket
import time
from typing import Callable, Iterator

import pytest

from fap_py import Master as FapMaster
from fap_py import Slave as FapSlave
from fap_py import execasync, mikroc
from fap_py.errors import FapTimeoutError, PortError


@pytest.fixture
def silent_port() -> Iterator[int]:
    """A listening socket that never accepts, its accept queue full: a SYN to it is
    dropped, so a connect waits out connect_ms (what a blackholed port does)."""
    with socket.socket() as lst:
        lst.bind(("127.0.0.1", 0))
        lst.listen(0)
        port = lst.getsockname()[1]
        fillers = []
        try:
            for _ in range(8):
                s = socket.socket()
                s.setblocking(False)
                s.connect_ex(("127.0.0.1", port))
                fillers.append(s)
            yield port
        finally:
            for s in fillers:
                s.close()


OPENERS: "dict[str, Callable[[str], object]]" = {
    "fap.Master": lambda url: FapMaster(url, slaves=[3]),
    "fap.Slave": lambda url: FapSlave(url, id=3),
    "execasync.Master": lambda url: execasync.Master(url),
    "execasync.Slave": lambda url: execasync.Slave(url, node=3, handler=lambda q: q.data),
    "mikroc.Master": lambda url: mikroc.Master(url),
}


@pytest.mark.parametrize("scheme", ["tcp", "rfc2217"])
@pytest.mark.parametrize("api", sorted(OPENERS))
def test_connect_timeout_is_a_port_error(api: str, scheme: str, silent_port: int) -> None:
    url = f"{scheme}://127.0.0.1:{silent_port}?connect_ms=200"
    t0 = time.monotonic()
    with pytest.raises(PortError) as ei:
        OPENERS[api](url)
    assert time.monotonic() - t0 < 5.0
    assert ei.value.errno == errno.ETIMEDOUT
    assert not isinstance(ei.value, FapTimeoutError)     # not "no reply" / "timed out"
    assert ei.value.strerror == f"{url}: open: connection timed out"


@pytest.mark.parametrize("scheme", ["tcp", "rfc2217"])
@pytest.mark.parametrize("argv", [
    ["fap", "master", "--slaves", "3", "01"],
    ["fap", "slave", "--id", "3", "01"],
    ["exec", "master", "--node", "3", "01"],
    ["exec", "slave", "--node", "3"],
    ["mikroc", "master", "--address", "3", "01"],
], ids=" ".join)
def test_connect_timeout_exits_3(argv: "list[str]", scheme: str, silent_port: int, fap) -> None:
    url = f"{scheme}://127.0.0.1:{silent_port}?connect_ms=200"
    r = fap(*argv[:2], "--port", url, *argv[2:])
    assert r.code == 3, r.err
    assert r.err == f"fap: error: {url}: open: connection timed out\n"
