"""`fap serve --protocol exec` with real client processes on a paced bus: every answer
goes to the client that asked, transactions never interleave on the wire, a client
killed mid-transaction costs the others nothing, a late reply is counted and
delivered to nobody, a second direct opener is refused with the daemon's pid."""
from __future__ import annotations

import json
import os
import signal
import subprocess

import pytest
from serve_helpers import client_proc, fap_cmd

from fap_py.execasync import Master, NoReplyError

N_CLIENTS, N_EACH = 4, 40


def test_clients_get_their_own_answers_and_never_interleave(served, vbus):
    procs = [client_proc(served.url, c, N_EACH, "sync" if c % 2 else "async") for c in range(N_CLIENTS)]
    results = []
    for p in procs:
        out, err = p.communicate(timeout=60)
        assert p.returncode == 0, err
        results.append(json.loads(out))
    assert sum(r["ok"] for r in results) == N_CLIENTS * N_EACH
    assert sum(r["bad"] for r in results) == 0                      # 0 misdelivered
    frames = vbus.spy_frames()
    assert len(frames) == 2 * N_CLIENTS * N_EACH, len(frames)
    for req, rep in zip(frames[::2], frames[1::2]):                  # 0 interleaved:
        assert (req.node, req.seq, req.data) == (rep.node, rep.seq, rep.data)   # each request, then its reply
    st = served.status()
    assert st["totals"]["transactions"] == N_CLIENTS * N_EACH
    assert st["totals"]["errors"] == 0 and st["totals"]["late"] == 0


def test_status_shows_clients_and_shares(served, vbus):
    with Master(served.url + "?weight=3", timeout=0.2) as m:
        for i in range(5):
            assert m.transact(5, bytes([i])) == bytes([i])
        st = served.status()
        me = [c for c in st["clients"] if c["name"] == "exec master"]
        assert len(me) == 1 and me[0]["weight"] == 3 and me[0]["transactions"] == 5
        assert me[0]["share"] == 1.0 and me[0]["pid"] == os.getpid()
        assert st["daemon"]["pid"] == served.pid and st["daemon"]["port_state"] == "open"
    out = subprocess.run(fap_cmd("serve", "status", served.url, "--json"), capture_output=True,
                         text=True, timeout=30)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["totals"]["transactions"] == 5
    text = subprocess.run(fap_cmd("serve", "status", served.url), capture_output=True, text=True,
                          timeout=30).stdout
    assert f"daemon pid {served.pid}: exec on {vbus.master_port}" in text


def test_stats_and_exceptions_are_a_direct_masters(served, vbus):
    with Master(served.url, timeout=0.02, retries=1) as m:
        with pytest.raises(NoReplyError):
            m.transact(9, b"x")                     # nobody is node 9: 2 attempts
        m.set_timeout(1.0, 0)                       # a loaded machine's slave answers in time
        assert m.transact(5, b"ok") == b"ok"
        st = m.stats
        assert (st.transactions, st.replies, st.failures, st.retries) == (2, 1, 1, 1)
        assert m.next_seq(5) == 1                   # 0 went with the first message


def test_a_client_killed_mid_transaction_costs_the_others_nothing(served, vbus):
    vbus.late_gate.clear()                          # node 6 answers when we say
    victim = subprocess.Popen([*fap_cmd("exec", "master", "--port", served.url, "--node", "6",
                                        "--timeout", "2", "--retries", "0", "01")],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert vbus.hold.wait(10)                       # its request is on the wire
    served.wait_for(lambda st: any(c["in_flight"] for c in st["clients"]))
    victim.send_signal(signal.SIGKILL)
    victim.communicate(timeout=10)
    vbus.late_gate.set()                            # the reply comes for a client that is gone
    served.wait_for(lambda st: st["totals"]["dropped"] == 1)
    with Master(served.url, timeout=0.2) as m:
        assert [m.transact(5, bytes([i])) for i in range(10)] == [bytes([i]) for i in range(10)]
    st = served.status()
    assert st["totals"]["errors"] == 0 and st["totals"]["late"] == 0


def test_a_late_reply_is_counted_and_delivered_to_nobody(served, vbus):
    vbus.late_gate.clear()
    with Master(served.url, timeout=0.05, retries=0) as m:
        with pytest.raises(NoReplyError):
            m.transact(6, b"late")
        vbus.late_gate.set()                        # now node 6 answers: after the timeout
        st = served.wait_for(lambda st: st["totals"]["late"] == 1)
        assert [c["late"] for c in st["clients"] if c["name"] == "exec master"] == [1]
        m.set_timeout(1.0, 0)
        assert m.transact(5, b"next") == b"next"    # the next answer is the next request's


def test_a_second_direct_opener_is_refused_naming_the_daemon(served, vbus):
    r = subprocess.run(fap_cmd("exec", "master", "--port", vbus.master_port, "--rs485", "none",
                               "--node", "5", "01"), capture_output=True, text=True, timeout=30)
    assert r.returncode == 3
    assert f"pid {served.pid}" in r.stderr and "serve" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_the_cli_works_unchanged_on_a_daemon_url(served, vbus):
    r = subprocess.run(fap_cmd("exec", "master", "--port", served.url, "--node", "5", "0102",
                               "--count", "3", "--json"), capture_output=True, text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    objs = [json.loads(x) for x in r.stdout.splitlines()]
    assert [o["data"] for o in objs if o["event"] == "reply"] == ["0102"] * 3
    assert objs[-1]["event"] == "stats" and objs[-1]["transactions"] == 3
    r = subprocess.run(fap_cmd("exec", "master", "--port", served.url, "--node", "9", "01",
                               "--timeout", "0.02", "--retries", "0"),
                       capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "no reply" in r.stdout + r.stderr   # as on a device path


def test_a_hot_unplug_is_told_to_clients_and_the_port_reopened(served, vbus):
    from fap_py.errors import PortGoneError

    with Master(served.url, timeout=1.0, retries=0) as m:
        assert m.transact(5, b"a") == b"a"
        m.set_timeout(0.05, 0)
        vbus.bus.disconnect(0, 1.0)                  # the daemon's adapter is pulled out
        with pytest.raises(PortGoneError):
            for _ in range(50):                      # the first write or read after it fails
                m.transact(5, b"b")
        st = served.status()
        assert st["daemon"]["port_state"] == "gone" and st["totals"]["port_gone"] == 1
        served.wait_for(lambda st: st["daemon"]["port_state"] == "open")
        m.set_timeout(1.0, 0)
        assert m.transact(5, b"c") == b"c"
        assert served.status()["totals"]["reopens"] == 1
        events = []
        while (ev := m._conn.next_event(0)) is not None:
            events.append(ev["event"])
        assert events == ["port_gone", "port_back"]


def test_a_daemon_that_dies_ends_its_clients_with_exit_3(served, vbus):
    client = subprocess.Popen(fap_cmd("exec", "master", "--port", served.url, "--node", "5", "01",
                                      "--count", "0", "--interval", "0.01", "--json"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert client.stdout is not None
    assert json.loads(client.stdout.readline())["event"] == "reply"    # it runs
    served.proc.send_signal(signal.SIGKILL)
    out, err = client.communicate(timeout=30)
    assert client.returncode == 3, err
    assert len(err.strip().splitlines()) == 1 and "daemon" in err and "Traceback" not in err


def test_weight_and_priority_are_bounded_by_the_daemon(served, vbus):
    with Master(served.url + "?weight=99&priority=9&name=greedy", timeout=0.5) as m:
        assert m.transact(5, b"g") == b"g"
        (me,) = [c for c in served.status()["clients"] if c["name"] == "greedy"]
        assert (me["weight"], me["priority"]) == (16, 3)       # --max-weight, --max-priority
    with Master(served.url, weight=2, priority=1) as m:         # the keywords, as the query
        m.transact(5, b"k")
        (me,) = [c for c in served.status()["clients"] if c["name"] == "exec master"]
        assert (me["weight"], me["priority"]) == (2, 1)


def test_threads_sharing_one_client_each_get_their_own_replies(served, vbus):
    import threading

    bad: list = []
    with Master(served.url, timeout=0.5, retries=2) as m:
        def worker(k: int) -> None:
            for i in range(20):
                tag = f"t{k}:{i}".encode()
                got = m.transact(5, tag)
                if got != tag:
                    bad.append((tag, got))

        threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert m.stats.transactions == 80
    assert bad == []
    assert served.status()["totals"]["transactions"] == 80


def test_a_cancelled_task_leaves_the_queue_or_ends_its_transaction(served, vbus):
    """asyncio cancellation reaches the daemon: a request still queued leaves the queue
    (never sent), the one on the bus ends as a direct master's cancelled one ends (a
    failure; the next one at once, not after its timeout); status counts both."""
    import asyncio
    import time

    vbus.late_gate.clear()                       # node 6 holds its answer until the gate opens
    with Master(served.url, timeout=5.0, retries=0) as m:
        async def main() -> float:
            running = asyncio.create_task(m.atransact(6, b"held"))
            while not vbus.hold.is_set():        # the slave has the request: it is on the bus
                await asyncio.sleep(0.005)
            queued = asyncio.create_task(m.atransact(5, b"never"))
            await asyncio.sleep(0.05)            # let it reach the daemon's queue
            for task in (queued, running):
                task.cancel()
                with pytest.raises(asyncio.CancelledError):
                    await task
            t0 = time.monotonic()
            assert await m.atransact(5, b"next") == b"next"
            return time.monotonic() - t0

        took = asyncio.run(main())
    vbus.late_gate.set()
    assert took < 4.0                            # not after the held one's 5 s timeout
    st = served.wait_for(lambda st: st["totals"]["cancelled"] == 2)
    assert st["totals"]["transactions"] == 2     # the held one and "next": "never" never ran
    assert b"never" not in b"".join(f.data for f in vbus.spy_frames())
    assert m.stats.failures == 2 and m.stats.replies == 1
