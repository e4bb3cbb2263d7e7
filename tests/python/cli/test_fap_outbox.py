"""Issue 33 item 4: `fap fap` says queued and sent apart, survives a full queue, bounds the
staleness of what a returning master gets, and exits 1 when messages were never sent.

Every wait is on the command's own output (its JSON lines), never a sleep."""
from __future__ import annotations

import collections
import json
import select
import signal
import subprocess
import time
from typing import Callable, Deque, Dict, List, Optional

from fap_py import RS485, RS485Mode
from fap_py import Master as FapMaster
from fap_py import Slave as FapSlave
from fap_py.vbus import VirtualBus

from .conftest import fap_cmd

LINE = RS485(mode=RS485Mode.NONE)
NONE = ["--rs485", "none"]


class Proc:
    """A `fap` process whose JSON lines are read as they come, each with its arrival time."""

    def __init__(self, *argv: str) -> None:
        self.p = subprocess.Popen(fap_cmd(*argv), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  bufsize=0)
        self.seen: List[tuple] = []     # (time read, object)
        self._buf = b""

    def until(self, cond: Callable[[dict], bool], timeout: float = 30) -> dict:
        """Objects until one satisfies ``cond`` (returned)."""
        assert self.p.stdout is not None
        end = time.monotonic() + timeout
        while True:
            while b"\n" in self._buf:
                line, self._buf = self._buf.split(b"\n", 1)
                obj = json.loads(line)
                self.seen.append((time.monotonic(), obj))
                if cond(obj):
                    return obj
            left = end - time.monotonic()
            r, _, _ = select.select([self.p.stdout], [], [], max(0.0, left))
            if not r:
                self.p.kill()
                raise AssertionError(f"not seen in time; last: {[o for _, o in self.seen[-5:]]}")
            chunk = self.p.stdout.read(65536)
            if not chunk:
                raise AssertionError(f"ended first: {self.p.wait()} {self.p.stderr.read()!r}")
            self._buf += chunk

    def stop(self, sig: Optional[int] = signal.SIGTERM) -> "tuple[int, List[dict], str]":
        if sig is not None:
            self.p.send_signal(sig)
        out, err = self.p.communicate(timeout=30)
        t = time.monotonic()
        rest = (self._buf + out).decode().splitlines()
        self.seen += [(t, json.loads(x)) for x in rest if x]
        return self.p.returncode, [o for _, o in self.seen], err.decode()


def _ev(name: str) -> Callable[[dict], bool]:
    return lambda o: o["event"] == name


def test_slave_without_a_master_queues_skips_and_drops_stale_then_delivers_fresh() -> None:
    """A slave sending every 20 ms with no master: each message says *queued* (never
    *sent*), a full backlog skips with a counted note instead of dying, messages older
    than --max-age are dropped and counted; when a master comes, what it gets is never
    older than --max-age (plus one pump), and each message it gets is then said *sent*."""
    max_age = 0.8
    with VirtualBus(ports=2) as bus:
        slave = Proc("fap", "slave", "--port", bus.paths[1], *NONE, "--id", "3", "--count", "0",
                     "--interval", "0.005", "--max-age", str(max_age), "--json", "01")
        try:
            slave.until(_ev("skipped"))     # > 64 waiting: skipped, and still running
            slave.until(_ev("stale"))       # the oldest dropped after --max-age
            assert not any(o["event"] == "sent" for _, o in slave.seen)
            with FapMaster(bus.paths[0], slaves=[3], id_cycle=0.05, rs485=LINE) as master:
                slave.until(_ev("sent"))
                got = 0
                while got < 64:                  # the backlog, then fresh messages
                    master.recv(timeout=10)
                    got += 1
                slave.until(lambda o: o["event"] == "sent" and
                            sum(x["event"] == "sent" for _, x in slave.seen) >= 64)
            code, objs, err = slave.stop()
        finally:
            slave.p.kill()
    assert code == 0, err                  # a slave is a server: SIGTERM is its normal end
    assert "transmit queue full" not in err and "Traceback" not in err
    skipped = [o for o in objs if o["event"] == "skipped"]
    stale = [o for o in objs if o["event"] == "stale"]
    assert skipped[0]["backlog"] == 64 and stale[0]["max_age"] == max_age
    # the age of every message sent: FIFO over the queued ("tx") lines, stale drops from the head
    waiting: Deque[float] = collections.deque()
    ages = []
    for t, o in slave.seen:
        if o["event"] == "tx":
            waiting.append(t)
        elif o["event"] == "stale":
            for _ in range(o["dropped"]):
                waiting.popleft()
        elif o["event"] == "sent":
            ages.append(t - waiting.popleft())
    assert len(ages) >= 64
    assert max(ages) < max_age + 0.5, max(ages)
    last = objs[-1]
    assert last["event"] == "stats"
    m: Dict[str, int] = last["messages"]
    assert m["skipped"] == sum(o["skipped"] for o in skipped)
    assert m["stale"] == sum(o["dropped"] for o in stale)
    assert m["sent"] == len(ages)
    assert m["queued"] == m["sent"] + m["stale"] + m["unsent"]


def test_slave_never_polled_exits_1_saying_what_was_not_sent() -> None:
    with VirtualBus(ports=2) as bus:
        r = subprocess.run(fap_cmd("fap", "slave", "--port", bus.paths[1], *NONE, "--id", "3",
                                   "--interval", "0", "--wait", "0.3", "0102", "03"),
                           capture_output=True, text=True, timeout=30)
    assert r.returncode == 1, r.stderr
    out = r.stdout.splitlines()
    assert out[1:3] == ["-> master: 01 02 (queued)", "-> master: 03 (queued)"]
    assert "(sent)" not in r.stdout
    assert "2 messages not sent: the master did not poll within 0.3 s" in out
    assert r.stderr.splitlines()[-1] == ("fap: error: 2 messages of 2 not sent (0 stale, 0 "
                                         "skipped, 2 unsent within --wait 0.3 s)")


def test_slave_polled_says_queued_then_sent_and_exits_0() -> None:
    with VirtualBus(ports=2) as bus, \
            FapMaster(bus.paths[0], slaves=[3], id_cycle=0.05, rs485=LINE) as master:
        r = subprocess.run(fap_cmd("fap", "slave", "--port", bus.paths[1], *NONE, "--id", "3",
                                   "--interval", "0", "0102"),
                           capture_output=True, text=True, timeout=30)
        assert master.recv(timeout=10).data == b"\x01\x02"
    assert r.returncode == 0, r.stderr
    out = r.stdout.splitlines()
    assert out.index("-> master: 01 02 (queued)") < out.index("-> master: 01 02 (sent)")


def test_master_whose_slave_went_away_exits_1_with_the_message_unsent() -> None:
    """The first message is sent; the slave then goes away (the master waits out its
    DATA_DONE window, 15 s): the second stays unsent past --wait, and that is exit 1 (it
    was exit 0 with '1 message still queued')."""
    with VirtualBus(ports=2) as bus:
        slave = FapSlave(bus.paths[1], id=3, rs485=LINE)
        master = Proc("fap", "master", "--port", bus.paths[0], *NONE, "--slaves", "3",
                      "--id-cycle", "0.05", "--count", "2", "--interval", "0.3", "--wait", "0.5",
                      "--json", "01")
        try:
            master.until(_ev("sent"))
            assert slave.recv(timeout=10).data == b"\x01"
            slave.close()
            code, objs, err = master.stop(None)
        finally:
            master.p.kill()
            slave.close()
    assert code == 1, err
    unsent = [o for o in objs if o["event"] == "unsent"]
    assert unsent == [{"event": "unsent", "messages": 1, "wait": 0.5}]
    assert objs[-1]["event"] == "stats" and objs[-1]["messages"]["unsent"] == 1
    assert err.splitlines()[-1].startswith("fap: error: 1 message of 2 not sent")
