"""Can ``fap monitor`` keep up with a saturated 1 Mbaud bus (100 kB/s)?

For each protocol: one second of back-to-back traffic at 1 Mbaud (100,000
bytes of typical request/answer frames), handed to the monitor in 100-byte
reads (what a reader polling every millisecond gets), with wire times on
(the timeline) and the statistics. CPU is measured with time.process_time;
"% of a core" is CPU seconds per second of bus traffic (the budget: 20 %).
A second column adds the JSON formatting of every record, a third the whole
command (``fap monitor --raw FILE --json``, child rusage, interpreter start
included).

    python bench/monitor/bench_monitor.py [--rounds N]

Run on an idle machine: a loaded 2-core box swings by tens of percent.
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from typing import Callable, Dict, List

from fap_py.execasync import encode as exec_encode
from fap_py.g485 import codec as g485
from fap_py.mikroc import encode as mikroc_encode
from fap_py.monitor.core import Monitor
from fap_py.monitor.output import json_line
from fap_py.monitor.stats import Stats

BAUD = 1_000_000
BUS_BYTES = BAUD // 10          # one second of a saturated bus
READ = 100                      # bytes per read at a 1 ms poll


def fap_frame(msg: int, dst: int, src: int, data: bytes = b"") -> bytes:
    from fap_py import _codec

    return _codec.find("fap").encode((msg, dst, src), data)


def traffic(protocol: str) -> bytes:
    """Typical request/answer pairs repeated to fill one second of the bus."""
    if protocol == "fap":
        cycle = b"".join(fap_frame(0, n, 0) + fap_frame(1, 0, n, bytes(range(32))) +
                         fap_frame(2, 0, n) for n in (1, 2, 3))
    elif protocol == "exec":
        cycle = b"".join(exec_encode(n, bytes(8), 1) + exec_encode(n, bytes(range(24)), 1)
                         for n in (1, 2, 3))
    elif protocol == "mikroc":
        cycle = b"".join(mikroc_encode(n, b"\x01\x02", from_master=True) +
                         mikroc_encode(n, b"\x03\x04\x05", from_master=False)
                         for n in (1, 2, 3))
    else:
        cycle = b"".join(g485.encode_read_request(n, 1, 10) + g485.encode_read_response(1, bytes(10))
                         for n in (1, 2, 3))
    return (cycle * (BUS_BYTES // len(cycle) + 1))[:BUS_BYTES]


def decode(data: bytes, protocol: str, fmt: Callable = None) -> int:
    mon = Monitor(protocol, BAUD)
    stats = Stats(BAUD)
    char_s = 10.0 / BAUD
    n = 0
    t = 0.0
    for i in range(0, len(data), READ):
        chunk = data[i:i + READ]
        for rec in mon.feed(chunk, t, char_s, None, 0):
            stats.add(rec)
            if fmt:
                fmt(rec)
            n += 1
        t += len(chunk) * char_s
    for rec in mon.finish():
        stats.add(rec)
        n += 1
    return n


def cpu(fn: Callable[[], object], rounds: int) -> float:
    best = float("inf")
    for _ in range(rounds):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def command_cpu(path: str, protocol: str) -> float:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-m", "fap_py", "monitor", "--protocol", protocol,
                    "--raw", path, "--json", "--baud", str(BAUD)],
                   stdout=subprocess.DEVNULL, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="best of N")
    args = ap.parse_args(argv)
    print(f"1 s of a saturated {BAUD} baud bus = {BUS_BYTES} bytes, {READ}-byte reads; "
          f"best of {args.rounds}; load avg {os.getloadavg()[0]:.2f}")
    print(f"{'protocol':<8} {'frames':>7} {'decode+stats':>14} {'+json':>10} {'command':>10}  budget 20 %")
    rows: Dict[str, float] = {}
    for protocol in ("fap", "exec", "mikroc", "g485"):
        data = traffic(protocol)
        frames = decode(data, protocol)
        c1 = cpu(lambda: decode(data, protocol), args.rounds)
        c2 = cpu(lambda: decode(data, protocol, json_line), args.rounds)
        with tempfile.NamedTemporaryFile(suffix=".bin") as fh:
            fh.write(data)
            fh.flush()
            c3 = min(command_cpu(fh.name, protocol) for _ in range(args.rounds))
        rows[protocol] = c1
        print(f"{protocol:<8} {frames:>7} {c1 * 100:>12.1f} % {c2 * 100:>8.1f} % {c3 * 100:>8.1f} %"
              f"  {'ok' if c1 < 0.20 else 'OVER'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
