"""docs/cli.md's stdin batches, walked over every command that reads payloads from stdin
(issue 33 item 7: `fap mikroc master -` aborted the whole batch on one line too long for
the protocol): a line that is not a payload (not hex, or over the protocol's size) is
reported and skipped, the rest is sent, and the command exits 2."""
from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import threading
from typing import Callable, ContextManager, Dict, Iterator, List

import pytest

from fap_py import RS485, RS485Mode, _protocols, execasync, mikroc
from fap_py import Master as FapMaster
from fap_py import Slave as FapSlave
from fap_py.cli import build_parser
from fap_py.vbus import VirtualBus

from .conftest import fap_cmd

LINE = RS485(mode=RS485Mode.NONE)
NONE = ["--rs485", "none"]


def _stdin_commands() -> List[str]:
    found = []

    def walk(p: argparse.ArgumentParser, words: tuple) -> None:
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            if any(a.dest == "data" and a.nargs == "*" for a in p._actions):
                found.append(" ".join(words))
            return
        seen = set()
        for name, child in subs[0].choices.items():
            if id(child) not in seen:
                seen.add(id(child))
                walk(child, words + (name,))

    walk(build_parser(), ())
    return sorted(found)


@contextlib.contextmanager
def _mikroc_echo(path: str) -> Iterator[None]:
    with mikroc.Slave(path, address=9, rs485=LINE) as s:
        done = threading.Event()

        def answer() -> None:
            while not done.is_set():
                try:
                    msg = s.receive(0.05)
                except Exception:
                    continue
                s.send(msg.data)

        t = threading.Thread(target=answer)
        t.start()
        try:
            yield
        finally:
            done.set()
            t.join(10)


#: command -> (argv after the port, the peer on the bus's second port, the event of a sent payload)
SETUP: Dict[str, tuple] = {
    "exec broadcast": ([], lambda p: contextlib.nullcontext(), "broadcast"),
    "exec master": (["--node", "5", "--timeout", "1"],
                    lambda p: execasync.Slave(p, node=5, handler=lambda q: q.data,
                                              rs485=LINE).start(), "reply"),
    "mikroc master": (["--address", "9", "--timeout", "1"], _mikroc_echo, "reply"),
    "fap master": (["--slaves", "3", "--interval", "0"],
                   lambda p: FapSlave(p, id=3, rs485=LINE), "sent"),
    "fap slave": (["--id", "3", "--interval", "0"],
                  lambda p: FapMaster(p, slaves=[3], id_cycle=0.05, rs485=LINE), "sent"),
}


def test_every_stdin_command_has_a_setup() -> None:
    assert _stdin_commands() == sorted(SETUP)


@pytest.mark.parametrize("command", sorted(SETUP))
def test_bad_stdin_lines_are_skipped_and_the_batch_goes_on(command: str) -> None:
    words = command.split()
    most = _protocols.get(words[0]).module().MAX_DATA
    argv, peer, sent_event = SETUP[command]
    stdin = "01\nzz\n" + "ab" * (most + 1) + "\n02\n"
    with VirtualBus(ports=2) as bus:
        peer_cm: Callable[[str], ContextManager] = peer
        with peer_cm(bus.paths[1]):
            r = subprocess.run(fap_cmd(*words, "--port", bus.paths[0], *NONE, *argv, "--json",
                                       "-"), input=stdin, capture_output=True, text=True,
                               timeout=60)
    objs = [json.loads(x) for x in r.stdout.splitlines()]
    bad = [o for o in objs if o["event"] == "bad_input"]
    assert [o["line"] for o in bad] == [2, 3], r.stdout
    assert bad[0]["error"] == "not hex bytes: 'zz' (use --text for text payloads)"
    assert bad[1]["error"].endswith(f"is 0..{most} bytes, not {most + 1}") or \
        bad[1]["error"].endswith(f"is 1..{most} bytes, not {most + 1}"), bad[1]
    assert [o["data"] for o in objs if o["event"] == sent_event] == ["01", "02"], r.stdout
    assert r.returncode == 2, r.stderr
    assert r.stderr.splitlines()[-1].startswith(
        "fap: error: 2 of 4 stdin lines were not payloads (skipped)"), r.stderr
