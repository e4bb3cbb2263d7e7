"""SIGINT and SIGTERM end every long-running command with its summary and the documented
exit code (issue 33 item 6; issue 32 item 13), walked from the CLI's own registry.

The registry is the parsers' ``long_running`` default (``fap_py.commands._node.long_running``):
a client (polling, scanning, reading stdin) ends on either signal with its summary
(``"interrupted": true``) and exit 130; a server (slave, sim) with its summary and exit 0.
A few commands handle their signals in their own module and are not tagged; they are
listed in :data:`SELF_HANDLED` with what docs/cli.md promises for them. Every leaf command
is in one of the two or in :data:`SHORT` (ends by itself, waits for nothing), so a new
long-running command cannot be missed.

Signals are sent only once the command said it is running (its first line), never after
a sleep.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, ContextManager, Dict, Iterator, List, Optional

import pytest

from fap_py import RS485, RS485Mode, execasync
from fap_py.cli import build_parser
from fap_py.g485 import SimDevice, Simulator
from fap_py.vbus import VirtualBus

from .conftest import fap_cmd

LINE = RS485(mode=RS485Mode.NONE)
NONE = ["--rs485", "none"]
CLIENT_EXIT, SERVER_EXIT = 130, 0


def _leaves(parser: argparse.ArgumentParser, path: tuple = ()) -> Iterator[tuple]:
    """(command words, parser) of every runnable command, aliases once."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    seen = set()
    for name, child in subs[0].choices.items():
        if id(child) in seen:
            continue
        seen.add(id(child))
        yield from _leaves(child, path + (name,))


EXAMPLE_SIM = Path(__file__).resolve().parents[3] / "examples" / "sim" / "site.toml"
LEAVES = {" ".join(words): p for words, p in _leaves(build_parser())}
REGISTRY = {name: p.get_default("long_running") for name, p in LEAVES.items()
            if p.get_default("long_running")}

#: long-running commands that install their own handlers (and do not register): the exit
#: codes of SIGTERM and SIGINT docs/cli.md gives them
SELF_HANDLED = {"bus": (0, 0), "monitor": (0, 130), "bridge": (0, 130), "sim": (0, 0), "web": (0, 0),
                "serve": (0, 0)}
#: commands that end by themselves and wait for nothing
SHORT = {"exec encode", "exec decode", "g485 write", "g485 set", "ports", "version",
         "completion", "doctor"}   # doctor: --listen SECONDS is bounded by its own time


def test_every_command_is_classified() -> None:
    assert REGISTRY, "no command registered as long-running"
    missing = set(LEAVES) - set(REGISTRY) - set(SELF_HANDLED) - SHORT
    assert not missing, f"commands neither long-running nor short: {sorted(missing)}"
    for name, p in LEAVES.items():        # what repeats or reads stdin must be registered
        opts = {o for a in p._actions for o in a.option_strings}
        takes_stdin = any(a.dest == "data" and a.nargs == "*" for a in p._actions)
        if "--count" in opts or "--first" in opts or takes_stdin:
            assert name in REGISTRY, f"{name} repeats, scans or reads stdin: not registered"
    assert set(REGISTRY.values()) <= {"client", "server"}


@dataclass
class Case:
    """How to run one command until it says it is running."""

    argv: Callable[[List[str]], List[str]]              # bus paths -> argv after `fap`
    started: Callable[[dict], bool]                     # its first JSON line(s)
    peers: Callable[[List[str]], ContextManager] = lambda paths: contextlib.nullcontext()
    summary: str = "stats"                              # the last object's event
    stdin: Optional[str] = None                         # written once it is running
    extra: Dict[str, object] = field(default_factory=dict)   # more keys of the summary


def _ev(name: str) -> Callable[[dict], bool]:
    return lambda o: o.get("event") == name


@contextlib.contextmanager
def _exec_slave(paths: List[str]):
    with execasync.Slave(paths[1], node=1, handler=lambda q: b"", rs485=LINE).start():
        yield


@contextlib.contextmanager
def _g485_device(paths: List[str]):
    with Simulator(paths[1], [SimDevice(1)]):
        yield


POLL = ["--count", "0", "--interval", "0.05", "--timeout", "0.01", "--retries", "0", "--json"]

CASES: Dict[str, Case] = {
    "exec master": Case(lambda p: ["exec", "master", "--port", p[0], *NONE, "--node", "9",
                                   *POLL, "01"], _ev("error"), extra={"interrupted": True}),
    "exec broadcast": Case(lambda p: ["exec", "broadcast", "--port", p[0], *NONE, "--json", "-"],
                           _ev("broadcast"), summary="summary", stdin="01\n",
                           extra={"interrupted": True, "broadcasts": 1}),
    "exec scan": Case(lambda p: ["exec", "scan", "--port", p[0], *NONE, "--timeout", "0.3",
                                 "--json"], _ev("found"), _exec_slave, summary="summary",
                      extra={"interrupted": True, "found": [1]}),
    "exec slave": Case(lambda p: ["exec", "slave", "--port", p[0], *NONE, "--node", "5",
                                  "--json"], _ev("ready")),
    "mikroc master": Case(lambda p: ["mikroc", "master", "--port", p[0], *NONE, "--address", "9",
                                     *POLL, "01"], _ev("error"), extra={"interrupted": True}),
    "mikroc slave": Case(lambda p: ["mikroc", "slave", "--port", p[0], *NONE, "--address", "5",
                                    "--json"], _ev("ready")),
    "g485 read": Case(lambda p: ["g485", "read", "--port", p[0], "--address", "9", "--register",
                                 "1", *POLL], _ev("error"), summary="summary",
                      extra={"interrupted": True}),
    "g485 error-word": Case(lambda p: ["g485", "error-word", "--port", p[0], "--address", "9",
                                       *POLL], _ev("error"), summary="summary",
                            extra={"interrupted": True}),
    "g485 handshake": Case(lambda p: ["g485", "handshake", "--port", p[0], "--address", "9",
                                      *POLL], _ev("error"), summary="summary",
                           extra={"interrupted": True}),
    "g485 scan": Case(lambda p: ["g485", "scan", "--port", p[0], "--timeout", "0.3", "--json"],
                      _ev("found"), _g485_device, summary="summary",
                      extra={"interrupted": True, "found": [1]}),
    "g485 sim": Case(lambda p: ["g485", "sim", "--port", p[0], "--address", "1", "--json"],
                     _ev("ready"), summary="summary"),
    "fap master": Case(lambda p: ["fap", "master", "--port", p[0], *NONE, "--slaves", "3",
                                  "--count", "0", "--json"], _ev("ready"),
                       extra={"interrupted": True}),
    "fap slave": Case(lambda p: ["fap", "slave", "--port", p[0], *NONE, "--id", "3", "--count",
                                 "0", "--json"], _ev("ready")),
    "demo": Case(lambda p: ["demo", "--json", "--duration", "60"], _ev("status"),
                 summary="summary", extra={"interrupted": True}),
    "bus": Case(lambda p: ["bus", "--ports", "2", "--json"], _ev("ready")),
    "serve": Case(lambda p: ["serve", "--protocol", "exec", "--port", p[0], *NONE, "--listen",
                             f"unix:{os.path.dirname(p[0])}/serve.sock", "--lock-dir",
                             os.path.dirname(p[0]), "--json"], _ev("ready")),
    "sim": Case(lambda p: ["sim", str(EXAMPLE_SIM), "--json"], _ev("ready"), summary="stopped"),
    "web": Case(lambda p: ["web", "--http", "127.0.0.1:0", "--port", p[0], "--json"], _ev("ready"),
                summary="stopped"),
}


def _popen(argv: List[str], **kw) -> subprocess.Popen:
    """The command as a process whose stdout is unbuffered bytes: a line read leaves the
    next ones in the pipe (select() sees them), none in a reader's buffer."""
    return subprocess.Popen(fap_cmd(*argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            bufsize=0, **kw)


def _communicate(p: subprocess.Popen) -> "tuple[str, str]":
    out, err = p.communicate(timeout=30)
    return out.decode(), err.decode()


def _read_until(p: subprocess.Popen, started: Callable[[dict], bool], timeout: float = 30) -> None:
    """Read ``p``'s stdout lines until one satisfies ``started`` (its own report)."""
    assert p.stdout is not None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        r, _, _ = select.select([p.stdout], [], [], max(0.0, end - time.monotonic()))
        if not r:
            break
        line = p.stdout.readline()
        if not line:
            break
        try:
            obj = json.loads(line)
        except ValueError:
            obj = {"line": line}
        if started(obj):
            return
    p.kill()
    raise AssertionError(f"the command never said it runs: {_communicate(p)}")


def _run_and_signal(case: Case, paths: List[str], sig: int) -> "tuple[int, List[dict], str]":
    with case.peers(paths):
        p = _popen(case.argv(paths), stdin=subprocess.PIPE if case.stdin is not None else None)
        try:
            if case.stdin is not None:
                assert p.stdin is not None
                p.stdin.write(case.stdin.encode())
            _read_until(p, case.started)
            t0 = time.monotonic()
            p.send_signal(sig)
            out, err = _communicate(p)
            assert time.monotonic() - t0 < 5, "the signal did not end it at once"
        finally:
            p.kill()
    objs = [json.loads(x) for x in out.splitlines() if x.startswith("{")]
    return p.returncode, objs, err


def _expected_exit(name: str, sig: int) -> int:
    kind = REGISTRY.get(name)
    if kind == "client":
        return CLIENT_EXIT
    if kind == "server":
        return SERVER_EXIT
    return SELF_HANDLED[name][0 if sig == signal.SIGTERM else 1]


def test_every_long_running_command_has_a_case() -> None:
    covered = set(CASES) | {"soak", "monitor", "bridge"}    # the last three: below / elsewhere
    assert set(REGISTRY) | set(SELF_HANDLED) <= covered


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_signal_gives_the_summary_and_the_documented_code(name: str, sig: int) -> None:
    case = CASES[name]
    with VirtualBus(ports=2) as bus:
        code, objs, err = _run_and_signal(case, bus.paths, sig)
    assert code == _expected_exit(name, sig), err
    assert "Traceback" not in err, err
    assert objs, f"{name}: no output"
    last = objs[-1]
    assert last.get("event") == case.summary, last
    for k, v in case.extra.items():
        assert last.get(k) == v, (k, last)


def _soak_slaves(pid: int) -> List[int]:
    """The soak's slave processes (``python -m fap_py.soak --child ...``): started inside
    its signal handling, unlike a helper an import may spawn (ctypes' find_library)."""
    try:
        kids = [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []
    found = []
    for k in kids:
        try:
            if b"--child" in Path(f"/proc/{k}/cmdline").read_bytes().split(b"\0"):
                found.append(k)
        except OSError:
            pass
    return found


def test_soak_sigterm_gives_the_results_so_far() -> None:
    """``fap soak`` prints nothing until a protocol's soak ends: it is running once its
    slave process is up (the condition polled, no fixed sleep)."""
    assert REGISTRY.get("soak") == "client"
    p = subprocess.Popen(fap_cmd("soak", "--protocol", "exec", "--seconds", "120", "--slaves",
                                 "1", "--json"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    try:
        end = time.monotonic() + 30
        while not _soak_slaves(p.pid) and time.monotonic() < end:
            time.sleep(0.05)
        assert _soak_slaves(p.pid), f"the soak started no slave: {p.poll()}"
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=30)
    finally:
        p.kill()
    assert p.returncode == 130, err
    res = [json.loads(x) for x in out.splitlines()]
    assert len(res) == 1 and res[0]["interrupted"] is True


def test_monitor_sigterm_is_its_documented_end() -> None:
    """``fap monitor --follow`` on a port: SIGTERM exits 0 with the summary (docs/cli.md)."""
    with VirtualBus(ports=2) as bus:
        p = subprocess.Popen(fap_cmd("monitor", "--port", bus.paths[0], "--protocol", "exec",
                                     "--follow"),
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            with execasync.Master(bus.paths[1], timeout=0.01, retries=0, rs485=LINE) as m:
                assert p.stdout is not None
                r: list = []
                end = time.monotonic() + 30
                while not r and time.monotonic() < end:     # until it shows a frame it saw
                    with contextlib.suppress(execasync.ExecAsyncError):
                        m.transact(3, b"\x01")
                    r, _, _ = select.select([p.stdout], [], [], 0.2)
                assert r, "the monitor showed nothing"
            p.send_signal(signal.SIGTERM)
            out, err = p.communicate(timeout=30)
        finally:
            p.kill()
    assert p.returncode == SELF_HANDLED["monitor"][0], err
    assert out.strip(), "no summary"


@pytest.mark.skipif(shutil.which("mosquitto") is None, reason="mosquitto not installed")
def test_bridge_sigterm_is_covered_by_its_service_tests() -> None:
    """``fap bridge`` (a server: SIGTERM exit 0 with ``{"event": "stopped"}``) is stopped
    that way against a real mosquitto in tests/python/bridge/test_bridge_service.py."""
    text = (Path(__file__).parents[1] / "bridge" / "test_bridge_service.py").read_text()
    assert "SIGTERM" in text


# -- issue 32 item 13: `fap fap master --wait` ends at once on a signal ----------------------

@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_fap_master_waiting_for_the_slave_stops_at_once(sig: int) -> None:
    """The master waits up to --wait (here 60 s) for slave 3, which never answers; a signal
    ends it at once with its counters and exit 130 (it waited out --wait, then exit 1)."""
    with VirtualBus(ports=2) as bus:
        p = _popen(["fap", "master", "--port", bus.paths[0], *NONE, "--slaves", "3", "--wait",
                    "60", "--json", "0102"])
        try:
            _read_until(p, _ev("ready"))           # printed before the wait starts
            t0 = time.monotonic()
            p.send_signal(sig)
            out, err = _communicate(p)
            took = time.monotonic() - t0
        finally:
            p.kill()
    assert p.returncode == 130, err
    assert took < 2.0, took
    last = json.loads(out.splitlines()[-1])
    assert last["event"] == "stats" and last["interrupted"] is True
    assert last["messages"]["queued"] == 0      # nothing was sent: the slave never answered


def test_fap_master_waiting_over_a_network_port_stops_at_once(tmp_path) -> None:
    """The same wait over tcp:// (a raw TCP server that accepts and never answers)."""
    import socket

    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        url = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
        p = _popen(["fap", "master", "--port", url, "--slaves", "3", "--wait", "60", "--json",
                    "0102"])
        try:
            conn, _ = srv.accept()
            with conn:
                _read_until(p, _ev("ready"))
                t0 = time.monotonic()
                p.send_signal(signal.SIGTERM)
                out, err = _communicate(p)
                took = time.monotonic() - t0
        finally:
            p.kill()
    assert p.returncode == 130, err
    assert took < 2.0, took
    assert json.loads(out.splitlines()[-1])["interrupted"] is True


def test_fap_master_wait_still_ends_with_exit_1() -> None:
    """Without a signal the wait is --wait long and says so (exit 1), as before."""
    with VirtualBus(ports=2) as bus:
        r = subprocess.run(fap_cmd("fap", "master", "--port", bus.paths[0], *NONE, "--slaves",
                                   "3", "--wait", "0.3", "0102"),
                           capture_output=True, text=True, timeout=30)
    assert r.returncode == 1
    assert r.stderr.splitlines()[-1] == \
        "fap: error: slave 3 did not answer the ID query within 0.3 s"


