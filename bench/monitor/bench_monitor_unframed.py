"""``fap monitor`` on streams without frame boundaries: CPU time per MB and
peak RSS of the whole command (``--raw FILE --json > /dev/null``) for every
protocol and ``auto``, on random bytes and on zeros, at two sizes (so the
rows show time linear in the input and memory flat).

    python bench/monitor/bench_monitor_unframed.py [--mb 64] [--small-mb 8]
        [--inputs random,zeros,ff] [--protocols fap,exec,mikroc,g485,auto]

Uses the installed ``fap`` (of this interpreter). A benchmark, not a test:
run it on an idle machine; the numbers go in docs/monitor.md.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable, Dict, List, Tuple

CHUNK = 1 << 20
INPUTS: Dict[str, Callable[[int], bytes]] = {
    "random": lambda n: os.urandom(n),
    "zeros": lambda n: bytes(n),
    "ff": lambda n: b"\xff" * n,              # G485's worst case: every byte a start byte
}


def fap_cmd() -> List[str]:
    script = Path(sys.executable).with_name("fap")
    return [str(script)] if script.exists() else [sys.executable, "-m", "fap_py"]


def write_input(path: Path, kind: str, mb: int) -> None:
    with open(path, "wb") as fh:
        for _ in range(mb):
            fh.write(INPUTS[kind](CHUNK))


def run(protocol: str, path: Path) -> Tuple[float, float, float]:
    """(CPU seconds, wall seconds, peak RSS MB) of one monitor run."""
    t0 = time.monotonic()
    with open(os.devnull, "wb") as null:
        proc = subprocess.Popen(fap_cmd() + ["monitor", "--protocol", protocol, "--raw",
                                             str(path), "--json"],
                                stdout=null, stderr=subprocess.DEVNULL)
        _pid, status, ru = os.wait4(proc.pid, 0)
    wall = time.monotonic() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"fap monitor --protocol {protocol} failed: status {status}")
    return ru.ru_utime + ru.ru_stime, wall, ru.ru_maxrss / 1024.0


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=int, default=64)
    ap.add_argument("--small-mb", type=int, default=8)
    ap.add_argument("--inputs", default="random,zeros")
    ap.add_argument("--protocols", default="fap,exec,mikroc,g485,auto")
    args = ap.parse_args(argv)
    print(f"# load average {os.getloadavg()[0]:.1f}; fap monitor --raw FILE --json > /dev/null")
    print("| input | protocol | MB | CPU s | CPU s/MB | wall s | peak RSS MB |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in args.inputs.split(","):
            for mb in (args.small_mb, args.mb):
                path = Path(tmp) / f"{kind}-{mb}.bin"
                write_input(path, kind, mb)
                for protocol in args.protocols.split(","):
                    cpu, wall, rss = run(protocol, path)
                    print(f"| {kind} | {protocol} | {mb} | {cpu:.1f} | {cpu / mb:.3f} | "
                          f"{wall:.1f} | {rss:.0f} |", flush=True)
                path.unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
