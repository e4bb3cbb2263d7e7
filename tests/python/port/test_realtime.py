"""The real-time option from Python, the CLI and the bridge config
(docs/realtime.md): the spec reaches C's parser and the engine's I/O
thread; a bad spec is an InvalidValueError (CLI: exit 2 naming --realtime);
a process without CAP_SYS_NICE gets RealTimeError at open."""
from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import threading
import time
from typing import Callable, List, Tuple

import pytest

from fap_py import RS485, RealTimeError, RS485Mode
from fap_py.bridge.config import BridgeConfigError, from_dict
from fap_py.errors import InvalidTypeError, InvalidValueError
from fap_py.rs485 import parse_realtime, port_options
from fap_py.vbus import VirtualBus

WAIT = 5.0


def _rt_threads(policy: int, prio: int) -> List[int]:
    """Thread ids of this process at ``policy`` / ``prio``."""
    out = []
    for tid in os.listdir("/proc/self/task"):
        try:
            if os.sched_getscheduler(int(tid)) == policy and \
                    os.sched_getparam(int(tid)).sched_priority == prio:
                out.append(int(tid))
        except OSError:   # the thread ended meanwhile
            pass
    return out


def _wait_for(cond: Callable[[], bool]) -> bool:
    end = time.monotonic() + WAIT
    while not cond():
        if time.monotonic() > end:
            return False
        time.sleep(0.005)
    return True


def _privileged() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except PermissionError:
        if os.environ.get("CI"):
            raise
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


needs_privilege = pytest.mark.skipif(not _privileged(),
                                     reason="no CAP_SYS_NICE here (CI requires it)")


def test_spec_reaches_c() -> None:
    po = port_options(115200, RS485(mode=RS485Mode.NONE, realtime="rr:7,mlock,cpu=0-1"))
    from fap_py._native import lib
    assert po.rt.policy == lib.FAP_RT_RR and po.rt.priority == 7
    assert po.rt.mlock == 1 and po.rt.cpus == 0b11
    po = port_options(115200, RS485())
    assert po.rt.policy == lib.FAP_RT_OFF and po.rt.mlock == 0 and po.rt.cpus == 0


@pytest.mark.parametrize("spec, says", [
    ("fifo:0", "'fifo:0'"), ("fifo:100", "1..99"), ("cpu=64", "'cpu=64'"),
    ("mlock,mlock", "given already"), ("off,fifo:3", "alone"), ("fast", "'fast'"),
    ("fifo:3,", "comma"), ("a\0b", "ASCII"), ("fifo:\udcff", "ASCII"),
])
def test_bad_spec_is_invalid_value(spec: str, says: str) -> None:
    with pytest.raises(InvalidValueError, match=says):
        RS485(realtime=spec)
    with pytest.raises(InvalidValueError, match="realtime"):
        parse_realtime(spec, "realtime")
    with pytest.raises(InvalidValueError, match=says):
        VirtualBus(ports=2, realtime=spec)


def test_spec_type() -> None:
    with pytest.raises(InvalidTypeError):
        RS485(realtime=50)  # type: ignore[arg-type]


def test_bad_cpu_refused_at_open() -> None:
    have = os.sched_getaffinity(0)
    missing = max(c for c in range(64) if c not in have)
    with pytest.raises(RealTimeError) as exc:
        VirtualBus(ports=2, realtime=f"cpu={missing}")
    assert exc.value.errno == errno.EINVAL and "CPU" in str(exc.value)


@needs_privilege
def test_every_engine_thread_gets_it() -> None:
    """FAP engine thread, exec async slave's serving thread, mikroC master's
    and G485 master's calling threads, the vbus relay: each at its asked
    policy and priority."""
    from fap_py import Master as FapMaster
    from fap_py.execasync import Slave as ExecSlave
    from fap_py.g485.errors import NoResponseError
    from fap_py.g485.master import G485Master
    from fap_py.mikroc import Master as MikroMaster

    with VirtualBus(ports=3, baud=115200, realtime="fifo:31") as bus:
        assert len(_rt_threads(os.SCHED_FIFO, 31)) == 1   # the relay
        with FapMaster(bus.paths[0], 115200, slaves=[],
                       rs485=RS485(mode=RS485Mode.NONE, realtime="fifo:32")):
            assert _wait_for(lambda: len(_rt_threads(os.SCHED_FIFO, 32)) == 1)
            assert os.sched_getscheduler(0) == os.SCHED_OTHER   # not the caller
        assert _rt_threads(os.SCHED_FIFO, 32) == []

        seen: List[Tuple[int, int]] = []

        def serve(slave: ExecSlave) -> None:
            slave.serve(timeout=0)
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

        with ExecSlave(bus.paths[1], 115200, node=1,
                       rs485=RS485(mode=RS485Mode.NONE, realtime="rr:33"),
                       handler=lambda req: None) as slave:
            t = threading.Thread(target=serve, args=(slave,))
            t.start()
            t.join(WAIT)
        assert seen == [(os.SCHED_RR, 33)]

        def poll() -> None:
            with MikroMaster(bus.paths[2], 115200,
                             rs485=RS485(mode=RS485Mode.NONE, realtime="fifo:34")) as m:
                m.send(1, b"x")
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

        t = threading.Thread(target=poll)
        t.start()
        t.join(WAIT)
        assert seen[-1] == (os.SCHED_FIFO, 34)

        def ask() -> None:   # G485: pure Python over fap_py.port, the caller's thread
            with G485Master(bus.paths[2], 115200, timeout=0.01, retries=0,
                            rs485=RS485(mode=RS485Mode.NONE, realtime="rr:35")) as m:
                with pytest.raises(NoResponseError):
                    m.read(1, 1)
            seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

        t = threading.Thread(target=ask)
        t.start()
        t.join(WAIT)
        assert seen[-1] == (os.SCHED_RR, 35)


_DROP = ["setpriv", "--bounding-set=-sys_nice,-ipc_lock", "--inh-caps=-sys_nice,-ipc_lock"]


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="setpriv (util-linux) missing")
def test_refused_without_privilege() -> None:
    """A child without CAP_SYS_NICE (and RLIMIT_RTPRIO 0): RealTimeError
    (errno EPERM) from a node's open and from the bus; the CLI exits 3."""
    code = (
        "import errno, resource\n"
        "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n"
        "from fap_py import RS485, RS485Mode, RealTimeError, Master\n"
        "from fap_py.vbus import VirtualBus\n"
        "try:\n"
        "    VirtualBus(ports=2, realtime='fifo:40')\n"
        "except RealTimeError as e:\n"
        "    assert e.errno == errno.EPERM and 'CAP_SYS_NICE' in str(e), e\n"
        "    print('bus refused')\n"
        "with VirtualBus(ports=2) as bus:\n"
        "    try:\n"
        "        Master(bus.paths[0], 115200, rs485=RS485(mode=RS485Mode.NONE,"
        " realtime='rr:40'))\n"
        "    except RealTimeError as e:\n"
        "        assert e.errno == errno.EPERM, e\n"
        "        print('node refused')\n"
        "    Master(bus.paths[0], 115200, rs485=RS485(mode=RS485Mode.NONE)).close()\n"
        "    print('plain ok')\n"
    )
    p = subprocess.run(_DROP + [sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["bus", "refused", "node", "refused", "plain", "ok"]
    p = subprocess.run(_DROP + [sys.executable, "-I", "-m", "fap_py", "bus", "--realtime",
                                "fifo:40"], capture_output=True, text=True, timeout=60,
                       preexec_fn=lambda: __import__("resource").setrlimit(
                           __import__("resource").RLIMIT_RTPRIO, (0, 0)))
    assert p.returncode == 3, (p.stdout, p.stderr)
    assert "CAP_SYS_NICE" in p.stderr and len(p.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("argv", [
    ["bus"], ["fap", "master"], ["fap", "slave"], ["exec", "master"], ["exec", "slave"],
    ["mikroc", "master"], ["mikroc", "slave"], ["g485", "read"], ["g485", "sim"],
])
def test_cli_bad_spec_exits_2(argv: List[str]) -> None:
    p = subprocess.run([sys.executable, "-I", "-m", "fap_py", *argv, "--realtime", "fifo:0"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2, (p.stdout, p.stderr)
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "--realtime" in lines[0] and "'fifo:0'" in lines[0], lines


def _bus(**kw: object) -> dict:
    return dict({"name": "line1", "port": "/dev/ttyUSB0", "protocol": "fap", "slaves": [1]},
                **kw)


def test_bridge_realtime_key() -> None:
    cfg = from_dict({"broker": {"url": "mqtt://127.0.0.1"},
                     "bus": [_bus(realtime="fifo:45,cpu=0")]})
    assert cfg.buses[0].rs485.realtime == "fifo:45,cpu=0"
    with pytest.raises(BridgeConfigError, match=r"realtime: real-time item 'fifo:450'"):
        from_dict({"broker": {"url": "mqtt://127.0.0.1"}, "bus": [_bus(realtime="fifo:450")]})
    with pytest.raises(BridgeConfigError, match="realtime"):
        from_dict({"broker": {"url": "mqtt://127.0.0.1"}, "bus": [_bus(realtime=45)]})
