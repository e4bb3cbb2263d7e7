"""A Python master here and three Python slaves in their own processes, one bus."""
from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time
from typing import List

from conftest import FAST, SLAVE_IDS, WAIT, wait_for_event
from fap_helpers import HERE, SlaveProcess

from fap_py import EventKind, Master, Message
from fap_py.vbus import VirtualBus


def _start(bus: VirtualBus) -> List[SlaveProcess]:
    procs = [SlaveProcess(p, sid) for p, sid in zip(bus.paths[1:], SLAVE_IDS)]
    for p in procs:
        p.expect("ready", WAIT)
    return procs


def test_exchange_across_processes(bus: VirtualBus) -> None:
    procs: List[SlaveProcess] = []
    with Master(bus.paths[0], slaves=SLAVE_IDS, **FAST) as master:
        try:
            procs = _start(bus)
            master.wait_active(timeout=WAIT)
            # master -> each slave, 1024 bytes; each echoes it back reversed
            payloads = {p.id: bytes((p.id + i) & 0xFF for i in range(1024)) for p in procs}
            for p in procs:
                master.send(payloads[p.id], to=p.id)
            for p in procs:
                assert p.expect("recv", WAIT) == f"recv 0 {payloads[p.id].hex()}"
            echoes = {m.source: m.data for m in (master.recv(timeout=WAIT) for _ in procs)}
            assert echoes == {sid: d[::-1] for sid, d in payloads.items()}
            # slave -> master and slave -> slave, started by commands to the processes
            a, b, c = procs
            a.command(f"send 0 {b'from a'.hex()}")
            a.expect("sent", WAIT)
            assert master.recv(timeout=WAIT) == Message(a.id, b"from a")
            c.command(f"send {b.id} {bytes(range(256)).hex() * 4}")
            c.expect("sent", WAIT)
            assert b.expect("recv", WAIT) == f"recv {c.id} {bytes(range(256)).hex() * 4}"
        finally:
            codes = [p.quit() for p in procs]
        assert codes == [0, 0, 0]
        st = master.stats
        assert st.data_rx >= 4 and st.crc_errors == 0 and st.framing_errors == 0


def test_killed_slave_process_is_marked_inactive_and_returns(bus: VirtualBus) -> None:
    procs: List[SlaveProcess] = []
    with Master(bus.paths[0], slaves=SLAVE_IDS, **FAST) as master:
        try:
            procs = _start(bus)
            master.wait_active(timeout=WAIT)
            list(master.events())
            victim = procs[2]
            victim.kill()                       # vanishes mid-protocol, no cleanup
            wait_for_event(master, EventKind.SLAVE_INACTIVE, victim.id)
            assert victim.id not in master.active_slaves
            procs[2] = SlaveProcess(bus.paths[3], victim.id)   # a new process, same port
            procs[2].expect("ready", WAIT)
            master.wait_active([victim.id], timeout=WAIT)
            master.send(b"are you new?", to=victim.id)
            assert procs[2].expect("recv", WAIT) == f"recv 0 {b'are you new?'.hex()}"
            assert master.recv(timeout=WAIT) == Message(victim.id, b"?wen uoy era")
            # the survivors kept working throughout
            master.send(b"ok", to=procs[0].id)
            assert procs[0].expect("recv", WAIT) == f"recv 0 {b'ok'.hex()}"
        finally:
            for p in procs:
                if p.proc.poll() is None:
                    p.quit()


def _sleeps_on_futex(pid: int) -> bool:
    with open(f"/proc/{pid}/wchan") as f:
        return f.read().startswith("futex")


def test_ctrl_c_interrupts_a_blocking_recv(bus: VirtualBus) -> None:
    child = textwrap.dedent(f"""
        import sys, time
        from fap_py import Slave
        with Slave({bus.paths[1]!r}, id=1) as s:
            t0 = time.monotonic()
            try:
                print("waiting", flush=True)
                s.recv()                       # no timeout
            except KeyboardInterrupt:
                print(f"interrupted {{time.monotonic() - t0:.3f}}", flush=True)
                sys.exit(3)
    """)
    # -I: import the installed fap_py, not the source tree in the cwd
    proc = subprocess.Popen([sys.executable, "-I", "-c", child], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "waiting", proc.stderr and proc.stderr.read()
        # wait until the child's main thread sleeps inside C (a futex: the
        # engine's condition variable), then press Ctrl-C
        deadline = time.monotonic() + WAIT
        while not _sleeps_on_futex(proc.pid):
            assert time.monotonic() < deadline, "child never blocked in recv"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=WAIT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 3, err
    assert out.startswith("interrupted"), (out, err)


def test_ctrl_c_storm_keeps_the_node_consistent(bus: VirtualBus) -> None:
    """KeyboardInterrupt landing anywhere inside node calls never leaves a
    stale 'thread inside C' count behind (close() would wait forever)."""
    proc = subprocess.Popen([sys.executable, "-I", str(HERE / "fap_sigint_child.py"),
                             bus.paths[1], "3000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: "queue.Queue[str]" = queue.Queue()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.put(line.strip())

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert lines.get(timeout=WAIT) == "ready"
        result = None
        deadline = time.monotonic() + 60
        while result is None:                  # signal storm until the child reports
            assert time.monotonic() < deadline, "child never finished"
            os.kill(proc.pid, signal.SIGINT)
            try:
                result = lines.get_nowait()
            except queue.Empty:
                pass
        assert lines.get(timeout=WAIT) == "closed"
        assert proc.wait(timeout=WAIT) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(WAIT)                       # EOF seen: the pipe can go
        for f in (proc.stdout, proc.stderr):
            if f is not None:
                f.close()
    fields = dict(kv.split("=") for kv in result.split())
    assert fields["users"] == "0"
    assert int(fields["hits"]) > 100, result          # the storm did hit node calls
