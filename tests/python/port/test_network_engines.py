"""Every protocol, both roles, through ser2net (raw tcp:// and rfc2217://).

A virtual bus has two ports; ser2net serves one raw and one as RFC 2217.
The master opens one URL and the slave the other (and the other way
round), so both roles and both transports carry every protocol's frames.
Then ser2net is killed and restarted under a running FAP master and
slave: the exchanges resume within 5 s of its return, losses counted.
"""
from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Dict, List, Tuple

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from net_helpers import WAIT, FaultProxy, Ser2net, wait_until

from fap_py import Master as FapMaster
from fap_py import Message
from fap_py import Slave as FapSlave
from fap_py.errors import FapError
from fap_py.vbus import VirtualBus

#: fast FAP timing (tests/python/fap/conftest.py does the same)
FAST = {"id_cycle": 0.05, "id_answer_timeout": 0.05, "data_done_timeout": 0.5}
ROLES = [(0, 1), (1, 0)]          # (master's URL, slave's URL): raw/rfc2217 and back
ROLE_IDS = ["master-raw-slave-rfc2217", "master-rfc2217-slave-raw"]


@pytest.mark.parametrize("roles", ROLES, ids=ROLE_IDS)
def test_fap_master_and_slave(served: Tuple[VirtualBus, Ser2net], roles: Tuple[int, int]) -> None:
    _, s = served
    with FapSlave(s.urls[roles[1]], 115200, id=3) as slave, \
            FapMaster(s.urls[roles[0]], 115200, slaves=[3], **FAST) as master:
        for i in range(5):
            data = bytes([i]) + b"\xff\r\n\r\x00" + bytes(range(64))
            master.send(data, to=3)
            assert slave.recv(timeout=WAIT) == Message(0, data)
            slave.send(data[::-1])
            assert master.recv(timeout=WAIT) == Message(3, data[::-1])


@pytest.mark.parametrize("roles", ROLES, ids=ROLE_IDS)
def test_exec_async_master_and_slave(served: Tuple[VirtualBus, Ser2net],
                                     roles: Tuple[int, int]) -> None:
    from fap_py.execasync import RS485, Master, RS485Mode, Slave

    none = RS485(mode=RS485Mode.NONE)
    _, s = served
    with Slave(s.urls[roles[1]], node=5, handler=lambda r: r.data[::-1], rs485=none).start(), \
            Master(s.urls[roles[0]], timeout=0.5, rs485=none) as master:
        for i in range(20):
            data = bytes([i, 0xFF, 0x10, 0x0D, 0x00, 0x0A])
            assert master.transact(5, data) == data[::-1]


@pytest.mark.parametrize("roles", ROLES, ids=ROLE_IDS)
def test_mikroc_master_and_slave(served: Tuple[VirtualBus, Ser2net],
                                 roles: Tuple[int, int]) -> None:
    from fap_py import RS485, RS485Mode
    from fap_py.mikroc import Master, Slave
    from fap_py.mikroc import Message as MMessage

    none = RS485(mode=RS485Mode.NONE)
    _, s = served
    with Master(s.urls[roles[0]], 115200, rs485=none) as master, \
            Slave(s.urls[roles[1]], 115200, 0x12, rs485=none) as slave:
        for i in range(10):
            req = bytes([i, 0xFF, 0x96])
            master.send(0x12, req)
            assert slave.receive(timeout=WAIT) == MMessage(0x12, req, True)
            slave.send(req[::-1])
            assert master.receive(timeout=WAIT) == MMessage(0x12, req[::-1], False)


@pytest.mark.parametrize("roles", ROLES, ids=ROLE_IDS)
def test_g485_master_and_simulator(served: Tuple[VirtualBus, Ser2net],
                                   roles: Tuple[int, int]) -> None:
    from fap_py.g485 import G485Master, SimDevice, Simulator

    _, s = served
    with Simulator(s.urls[roles[1]], [SimDevice(2)], baudrate=115200), \
            G485Master(s.urls[roles[0]], 115200, timeout=0.5) as master:
        for _ in range(5):
            master.handshake(2)
        master.write(2, 8, [0x32, 0x10])
        assert master.read(2, 8, 2) == bytes([0x32, 0x10])


def _counted_losses(st: object) -> int:
    """DATA frames the master's counters say may not have arrived (FAP has no
    acknowledgement): written into a dead link, sent to a slave not active
    then, sent to one marked inactive afterwards, or dropped from the queue."""
    return sum(getattr(st, k) for k in ("write_errors", "tx_to_inactive", "tx_unconfirmed",
                                        "tx_dropped"))


def _example(name: str) -> Path:
    """A built example program (the meson build directory next to the sources)."""
    root = Path(__file__).resolve().parents[3]
    for build in (os.environ.get("FAP_BUILD_DIR"), root / "build"):
        if build and (Path(build) / "examples" / "fap" / name).exists():
            return Path(build) / "examples" / "fap" / name
    pytest.skip(f"examples/fap/{name} is not built")


def test_classic_api_programs_through_ser2net(served: Tuple[VirtualBus, Ser2net]) -> None:
    """The vendor API's example master and slave, unchanged, given URLs as
    their device: fapInit("rfc2217://...") and fapInit("tcp://...")."""
    import subprocess

    _, s = served
    slave = subprocess.Popen([str(_example("fap_slave")), s.urls[1], "7", "3"],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert slave.stdout is not None
        ready = slave.stdout.readline().strip()
        assert ready == "slave 7 ready", (ready, s.log.read_text()[-2000:])
        master = subprocess.run([str(_example("fap_master")), s.urls[0], "7", "3"],
                                capture_output=True, text=True, timeout=120)
        assert master.returncode == 0, master.stdout + master.stderr
        assert "master: 3 of 3 replies" in master.stdout
        assert "reply from 7: slave 7 got: hello 2 from the master" in master.stdout
        out, _ = slave.communicate(timeout=WAIT)
        assert slave.returncode == 0, out
    finally:
        if slave.poll() is None:
            slave.kill()
            slave.communicate()


class Traffic:
    """Numbered messages master -> slave 3, one every few ms, until stopped:
    ``sent`` and ``got`` hold (time, number) for each message sent / received."""

    def __init__(self, master: FapMaster, slave: FapSlave) -> None:
        self.master, self.slave = master, slave
        self.sent: List[Tuple[float, int]] = []
        self.got: List[Tuple[float, int]] = []
        self.stop = threading.Event()
        self.done_sending = threading.Event()
        self.threads = [threading.Thread(target=self._send), threading.Thread(target=self._recv)]
        for t in self.threads:
            t.start()

    def _send(self) -> None:
        n = 0
        while not self.stop.wait(0.005):     # the traffic's pace, not synchronisation
            try:
                self.master.send(n.to_bytes(4, "big"), to=3)
                self.sent.append((time.monotonic(), n))
            except FapError:                 # queue full while the link is down: not sent
                pass
            n += 1

    def _recv(self) -> None:
        while True:
            try:
                msg = self.slave.recv(timeout=0.2)
            except FapError:
                msg = None
            if msg is not None:
                self.got.append((time.monotonic(), int.from_bytes(msg.data, "big")))
            elif self.done_sending.is_set():
                return                       # sent, flushed, and nothing more came

    def received_after(self, t0: float) -> int:
        """How many messages sent after t0 have arrived."""
        first = next((n for ts, n in list(self.sent) if ts > t0), None)
        return 0 if first is None else sum(1 for _, n in list(self.got) if n >= first)

    def close(self) -> None:
        """Stop sending, wait until what was queued is on the wire, then until
        the receiver has taken everything (it ends on its first empty receive
        after the stop)."""
        self.stop.set()
        self.threads[0].join(WAIT)
        self.done_sending.set()
        self.master.flush(timeout=WAIT)
        self.threads[1].join(WAIT)

    def check(self) -> int:
        """Nothing duplicated, nothing reordered, nothing corrupt; returns the losses."""
        numbers = [n for _, n in self.got]
        assert numbers == sorted(set(numbers))
        assert set(numbers) <= {n for _, n in self.sent}
        return len(self.sent) - len(numbers)


#: the vendor's 15 s ID cycle and DATA_DONE window: a restart must not wait them out
VENDOR = {"id_answer_timeout": 0.05, "id_cycle": 15.0, "data_done_timeout": 15.0}


@pytest.mark.parametrize("timing", [FAST, VENDOR], ids=["fast", "vendor-15s"])
def test_fap_survives_a_ser2net_restart(served: Tuple[VirtualBus, Ser2net],
                                        timing: Dict[str, float]) -> None:
    _, s = served
    with FapSlave(s.urls[1], 115200, id=3) as slave, \
            FapMaster(s.urls[0], 115200, slaves=[3], **timing) as master:
        traffic = Traffic(master, slave)
        try:
            wait_until(lambda: len(traffic.got) >= 5, "exchanges before the restart")
            s.stop()
            s.start()
            back = time.monotonic()
            wait_until(lambda: traffic.received_after(back) >= 1, "exchanges after the restart")
            resumed = time.monotonic() - back
            wait_until(lambda: traffic.received_after(back) >= 5, "steady again")
        finally:
            traffic.close()
        lost = traffic.check()
        st = master.stats
        print(f"resumed {resumed:.3f} s after ser2net's return, lost {lost} of {len(traffic.sent)}; "
              f"write_errors {st.write_errors} tx_unconfirmed {st.tx_unconfirmed} "
              f"tx_to_inactive {st.tx_to_inactive} tx_dropped {st.tx_dropped}")
        assert lost <= _counted_losses(st)
        assert resumed < 5.0
        # both ends saw the server go and come back: counted like any vanished port
        for node in (master, slave):
            st = node.stats
            assert st.port_lost >= 1 and st.port_reopened >= 1


def test_fap_through_a_resetting_jittery_proxy(served: Tuple[VirtualBus, Ser2net]) -> None:
    """Delay, jitter, one-byte segments and connection resets between the
    master and ser2net: every message that arrives is whole and in order,
    losses are counted, reconnects take under 5 s."""
    _, s = served
    with FaultProxy(s.ports[0]) as px, FapSlave(s.urls[1], 115200, id=3) as slave, \
            FapMaster(px.url("tcp"), 115200, slaves=[3], **FAST) as master:
        px.split, px.delay, px.jitter = True, 0.001, 0.002
        traffic = Traffic(master, slave)
        reconnects = []
        try:
            for _ in range(3):
                wait_until(lambda: len(traffic.got) >= 3, "exchanges")
                before = px.connections
                px.reset()
                cut = time.monotonic()
                wait_until(lambda: px.connections > before, "the reconnect")
                reconnects.append(time.monotonic() - cut)
                wait_until(lambda: traffic.received_after(cut + reconnects[-1]) >= 1,
                           "an exchange after it")
        finally:
            traffic.close()
        lost = traffic.check()
        print(f"reconnect s: {[round(r, 3) for r in reconnects]}, "
              f"sent {len(traffic.sent)}, lost {lost}")
        assert max(reconnects) < 5.0
        st = master.stats
        assert st.port_lost >= 3 and st.port_reopened >= 3     # every reset counted
        assert lost <= _counted_losses(st)


def _until_ok(fn: Callable[[], object], what: str) -> float:
    """Call fn until it stops raising a port or bus error; the seconds it took."""
    t0 = time.monotonic()

    def attempt() -> bool:
        try:
            fn()
            return True
        except FapError:
            return False

    wait_until(attempt, what)
    return time.monotonic() - t0


def test_exec_master_reconnects_after_a_reset(served: Tuple[VirtualBus, Ser2net]) -> None:
    """exec async reports the dropped connection like a vanished device
    (PortGoneError); reopen() connects again and the exchanges go on."""
    from fap_py.errors import PortGoneError
    from fap_py.execasync import RS485, Master, RS485Mode, Slave

    none = RS485(mode=RS485Mode.NONE)
    _, s = served
    with FaultProxy(s.ports[0]) as px, \
            Slave(s.urls[1], node=5, handler=lambda r: r.data, rs485=none).start(), \
            Master(px.url("tcp"), timeout=0.5, retries=1, rs485=none) as master:
        assert master.transact(5, b"before") == b"before"
        px.reset()
        with pytest.raises(PortGoneError):
            for _ in range(50):                  # the reset reaches the next call or the one after
                master.transact(5, b"lost?")
        took = _until_ok(master.reopen, "the reopen")
        assert took < 5.0
        assert master.transact(5, b"after") == b"after"
        assert master.stats.replies >= 2


def test_g485_master_reopens_by_itself_after_a_reset(served: Tuple[VirtualBus, Ser2net]) -> None:
    from fap_py.g485 import G485Master, SimDevice, Simulator

    _, s = served
    with FaultProxy(s.ports[1]) as px, \
            Simulator(s.urls[0], [SimDevice(2)], baudrate=115200), \
            G485Master(px.url("rfc2217"), 115200, timeout=0.5) as master:
        master.handshake(2)
        px.reset()
        took = _until_ok(lambda: master.handshake(2), "a handshake after the reset")
        assert took < 5.0
        assert master.stats.reopens >= 1
