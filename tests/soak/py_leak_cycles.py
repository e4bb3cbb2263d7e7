#!/usr/bin/env python3
"""Python leak check: many open/close cycles of every fap_py handle kind
(virtual bus, FAP master and slave, exec async master and slave, mikroC
master and slave, G485 master); RSS, fds and threads must stay flat.

    py_leak_cycles.py [--cycles N] [--rss-growth-kib K]

Exit 1 when fds or threads grew, or RSS grew more than K KiB between the
end of the warm-up (first quarter) and the end."""
import argparse
import gc
import os
import sys
import threading


def sample() -> tuple:
    rss = 0
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1])
    return rss, len(os.listdir("/proc/self/fd")), threading.active_count(), \
        len(os.listdir("/proc/self/task"))


def one_cycle() -> None:
    from fap_py import execasync, mikroc
    from fap_py.fap import Master, Slave
    from fap_py.g485 import G485Master
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=3) as bus:
        with Master(bus.paths[0], slaves=[1], id_answer_timeout=0.01) as m, \
                Slave(bus.paths[1], id=1) as s:
            m.send(b"x", to=1)
            assert s.stats.frames_rx >= 0
        with execasync.Master(bus.paths[0]) as em, \
                execasync.Slave(bus.paths[1], node=2, handler=lambda r: r.data) as es:
            _ = em.stats
            _ = es.stats
        with mikroc.Master(bus.paths[0]) as mm, mikroc.Slave(bus.paths[1], address=5) as ms:
            _ = mm.stats
            _ = ms.stats
        with G485Master(bus.paths[2]) as g:
            _ = g.stats


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cycles", type=int, default=200)
    ap.add_argument("--rss-growth-kib", type=int, default=2048)
    a = ap.parse_args()
    warm = max(1, a.cycles // 4)
    for _ in range(warm):
        one_cycle()
    gc.collect()
    r0, f0, t0, k0 = sample()
    for _ in range(a.cycles - warm):
        one_cycle()
    gc.collect()
    r1, f1, t1, k1 = sample()
    print(f"py_leak_cycles: {a.cycles} cycles; RSS {r0} -> {r1} KiB, fds {f0} -> {f1}, "
          f"threads {t0} -> {t1} (tasks {k0} -> {k1})")
    bad = f1 > f0 or t1 > t0 or k1 > k0 or r1 - r0 > a.rss_growth_kib
    if bad:
        print("py_leak_cycles: FAILED: a resource grew", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
