"""Issue 33 item 8: docs/cli.md promises that every ``--json`` object carries an
``"event"`` key. This walks the CLI's registry (every leaf command of
``fap_py.cli.build_parser``), runs each one with ``--json`` against real nodes
on virtual buses (servers as processes ended with SIGTERM, clients through
``fap_py.cli.main``), and checks every line it prints is a JSON object with
an ``event``. A command added to the registry without a recipe here fails
the test, so the promise is kept for new commands too."""
from __future__ import annotations

import argparse
import json
import os
import queue
import signal
import subprocess
import threading
from pathlib import Path
from typing import Callable, Dict, List, Tuple

import pytest

from fap_py.cli import build_parser
from fap_py.execasync import encode
from fap_py.vbus import VirtualBus

from .conftest import fap_cmd

WAIT_S = 20.0
NET = ("--rs485", "none")


def _leaves() -> List[Tuple[str, ...]]:
    found: List[Tuple[str, ...]] = []

    def walk(path: Tuple[str, ...], parser: argparse.ArgumentParser) -> None:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            found.append(path)
        for action in subs:
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) not in seen:          # aliases (exec poll = exec master) once
                    seen.add(id(sub))
                    walk(path + (name,), sub)

    walk((), build_parser())
    return found


class Server:
    """A long-running command with --json as a process: its lines, its end."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(fap_cmd(*args, "--json"), stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True,
                                     env=dict(os.environ, COLUMNS="100"))
        self.lines: "queue.Queue[object]" = queue.Queue()
        self.out: List[str] = []
        threading.Thread(target=self._pump, daemon=True).start()
        while True:           # up to its readiness object
            line = self.lines.get(timeout=WAIT_S)
            assert isinstance(line, str), (args, self.proc.stderr.read())
            self.out.append(line)
            if '"ready"' in line:
                return

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line)
        self.lines.put(None)

    def stop(self) -> List[str]:
        self.proc.send_signal(signal.SIGTERM)
        self.proc.wait(timeout=WAIT_S)
        while (line := self.lines.get(timeout=WAIT_S)) is not None:
            self.out.append(line)   # type: ignore[arg-type]
        assert self.proc.returncode == 0, self.proc.stderr.read()
        return self.out


Run = Callable[..., List[str]]


@pytest.fixture
def run(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> Run:
    """run(*argv, codes=(0,)) -> stdout lines of ``fap ... --json`` in this process."""
    from fap_py.cli import main

    monkeypatch.setenv("COLUMNS", "100")

    def _run(*args: str, codes: Tuple[int, ...] = (0,)) -> List[str]:
        code = main([*args, "--json"])
        cap = capsys.readouterr()
        assert code in codes, (args, code, cap.err)
        return cap.out.splitlines()

    return _run


def _exec(run: Run, tmp: Path) -> Dict[Tuple[str, ...], List[str]]:
    with VirtualBus(ports=2) as bus:
        slave = Server("exec", "slave", "--port", bus.paths[0], "--node", "5", *NET)
        out = {
            ("exec", "master"): run("exec", "master", "--port", bus.paths[1], "--node", "5", *NET,
                                    "--timeout", "2", "0102")
            + run("exec", "master", "--port", bus.paths[1], "--node", "9", *NET, "--timeout",
                  "0.05", "--retries", "0", "01", codes=(1,)),
            ("exec", "scan"): run("exec", "scan", "--port", bus.paths[1], "--first", "4",
                                  "--last", "6", "--timeout", "0.2", *NET),
            ("exec", "broadcast"): run("exec", "broadcast", "--port", bus.paths[1], *NET, "01"),
        }
        out[("exec", "slave")] = slave.stop()
    frame = encode(5, b"ABC", 1).hex()
    out[("exec", "encode")] = run("exec", "encode", "--node", "5", "0102")
    out[("exec", "decode")] = run("exec", "decode", frame) + \
        run("exec", "decode", frame[:10], codes=(1,))
    return out


def _mikroc(run: Run, tmp: Path) -> Dict[Tuple[str, ...], List[str]]:
    with VirtualBus(ports=2) as bus:
        slave = Server("mikroc", "slave", "--port", bus.paths[0], "--address", "5", *NET)
        master = run("mikroc", "master", "--port", bus.paths[1], "--address", "5", *NET,
                     "--timeout", "2", "0102")
        return {("mikroc", "master"): master, ("mikroc", "slave"): slave.stop()}


def _g485(run: Run, tmp: Path) -> Dict[Tuple[str, ...], List[str]]:
    with VirtualBus(ports=2) as bus:
        sim = Server("g485", "sim", "--port", bus.paths[0], "--address", "1", *NET)
        p = ("--port", bus.paths[1], *NET, "--timeout", "1")
        out = {
            ("g485", "read"): run("g485", "read", *p, "--address", "1", "--register", "1",
                                  "--registers", "2"),
            ("g485", "write"): run("g485", "write", *p, "--address", "1", "--register", "8",
                                   "0x32"),
            ("g485", "set"): run("g485", "set", *p, "--address", "1", "save_eeprom"),
            ("g485", "error-word"): run("g485", "error-word", *p, "--address", "1"),
            ("g485", "handshake"): run("g485", "handshake", *p, "--address", "1"),
            ("g485", "scan"): run("g485", "scan", "--port", bus.paths[1], *NET, "--timeout",
                                  "0.1", "--first", "1", "--last", "2"),
        }
        out[("g485", "sim")] = sim.stop()
        return out


def _fap(run: Run, tmp: Path) -> Dict[Tuple[str, ...], List[str]]:
    with VirtualBus(ports=2) as bus:
        slave = Server("fap", "slave", "--port", bus.paths[0], "--id", "3", "--count", "0",
                       *NET, "--interval", "0.1", "6869")
        master = run("fap", "master", "--port", bus.paths[1], "--slaves", "3", "--to", "3",
                     *NET, "--interval", "0.5", "--id-answer-timeout", "0.2", "6869")
        return {("fap", "master"): master, ("fap", "slave"): slave.stop()}


def _tools(run: Run, tmp: Path) -> Dict[Tuple[str, ...], List[str]]:
    cap = tmp / "bus.cap"
    cap.write_text("# fap-vbus-capture 1 ports=2 baud=9600 echo=0 seed=0\n"
                   f"1000 0 {encode(5, b'AB', 1).hex(' ')}\n2000 1 00 01 55\n")
    conf = tmp / "bridge.toml"
    conf.write_text("[broker]\nurl = 'mqtt://x'\n[[bus]]\nname = 'l'\nport = '/dev/null'\n"
                    "protocol = 'fap'\nslaves = [1]\n")
    out = {
        ("version",): run("version"),
        ("completion",): run("completion", "bash"),
        ("monitor",): run("monitor", "--capture", str(cap), "--protocol", "exec")
        + run("monitor", "--capture", str(cap), "--protocol", "exec", "--stats"),
        ("bridge",): run("bridge", "--config", str(conf), "--check"),
    }
    web = Server("web", "--http", "127.0.0.1:0", "--capture", str(cap), "--protocol", "exec")
    out[("web",)] = web.stop()
    bus = Server("bus", "--ports", "2", "--echo", "--link-dir", str(tmp / "links"))
    port0 = str(tmp / "links" / "port0")
    out[("ports",)] = run("ports", "--no-probe") + run("ports", "--device", port0) + \
        run("ports", "--check", port0, "--rounds", "1", codes=(0, 1))
    out[("bus",)] = bus.stop()
    return out


def _runs(run: Run, tmp: Path) -> Dict[Tuple[str, ...], List[str]]:
    return {
        ("demo",): run("demo", "--duration", "0.3", "--slaves", "1"),
        ("soak",): run("soak", "--protocol", "mikroc", "--seconds", "0.3",
                       "--check8-seconds", "0.1", "--slaves", "1"),
        ("sim",): _sim(run, tmp),
        ("doctor",): _doctor(run, tmp),
        ("serve",): _serve(run, tmp),
    }


def _serve(run: Run, tmp: Path) -> List[str]:
    with VirtualBus(ports=2) as bus:
        sock = tmp / "serve.sock"
        daemon = Server("serve", "--protocol", "exec", "--port", bus.paths[0], *NET, "--listen",
                        f"unix:{sock}", "--lock-dir", str(tmp))
        out = run("serve", "status", f"fapd://{sock}")
        out += run("serve", "--protocol", "exec", "--port", bus.paths[1], *NET, "--listen",
                   f"unix:{tmp}/check.sock", "--lock-dir", str(tmp), "--check")
        return out + daemon.stop()


def _doctor(run: Run, tmp: Path) -> List[str]:
    root = tmp / "root"                 # an empty machine: findings, and their exit code
    (root / "etc").mkdir(parents=True)
    return run("doctor", "--root", str(root), codes=(0, 4, 5))


def _sim(run: Run, tmp: Path) -> List[str]:
    example = str(Path(__file__).resolve().parents[3] / "examples" / "sim" / "site.toml")
    sock = f"unix:{tmp}/sim.sock"
    sim = Server("sim", example, "--control", sock)
    out = run("sim", "--check", example) + run("sim", "status", "--control", sock)
    out += run("sim", "fault", "add", "off", "--node", "5", "--control", sock)
    out += run("sim", "fault", "list", "--control", sock)
    out += run("sim", "fault", "remove", "all", "--control", sock)
    return out + sim.stop()


GROUPS = {"exec": _exec, "mikroc": _mikroc, "g485": _g485, "fap": _fap, "tools": _tools,
          "runs": _runs}
COVERED: Dict[Tuple[str, ...], str] = {
    ("exec", "master"): "exec", ("exec", "scan"): "exec", ("exec", "broadcast"): "exec",
    ("exec", "slave"): "exec", ("exec", "encode"): "exec", ("exec", "decode"): "exec",
    ("mikroc", "master"): "mikroc", ("mikroc", "slave"): "mikroc",
    ("g485", "read"): "g485", ("g485", "write"): "g485", ("g485", "set"): "g485",
    ("g485", "error-word"): "g485", ("g485", "handshake"): "g485", ("g485", "scan"): "g485",
    ("g485", "sim"): "g485", ("fap", "master"): "fap", ("fap", "slave"): "fap",
    ("version",): "tools", ("completion",): "tools", ("monitor",): "tools",
    ("bridge",): "tools", ("demo",): "runs", ("soak",): "runs", ("sim",): "runs", ("doctor",): "runs",
    ("ports",): "tools",
    ("bus",): "tools",
    ("serve",): "runs",
    ("web",): "tools",
}


def test_every_registry_command_has_a_json_recipe() -> None:
    assert sorted(_leaves()) == sorted(COVERED), "add the new command to COVERED and a group"


@pytest.mark.parametrize("group", sorted(GROUPS))
def test_every_json_object_has_an_event(group: str, run: Run, tmp_path: Path) -> None:
    outputs = GROUPS[group](run, tmp_path)
    assert sorted(outputs) == sorted(k for k, g in COVERED.items() if g == group)
    for command, lines in outputs.items():
        assert lines, f"fap {' '.join(command)} --json printed nothing"
        for line in lines:
            obj = json.loads(line)
            assert isinstance(obj, dict), (command, line)
            assert isinstance(obj.get("event"), str) and obj["event"], \
                f"fap {' '.join(command)} --json: no \"event\" in {line[:200]}"
