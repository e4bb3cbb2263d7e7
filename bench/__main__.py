"""``python -m bench``: every benchmark of the project in one run, with plots.

Run from the repository root after ``meson setup build && meson compile -C
build`` and ``pip install '.[bench]'`` (fap_py, matplotlib and the Python
peers). Every exchange runs on a virtual bus (``fap_py.vbus``) opened here;
the two sides of an exchange are separate processes
(``build/bench/wire/bench_wire`` for the C engines and libmodbus,
``bench/g485/bench_g485.py`` for the Python libraries), so each side's CPU
is its own and the bus relay's is nobody's.

Measured (medians of ``--rounds`` runs, with min and max):

* paced efficiency at 9600, 115200 and 1,000,000 baud: exchanges/s as a
  share of the framing limit (10 bits per byte, request + reply bytes; a
  Modbus 3.5-character silence is not counted: the peers do not keep it on
  a pty), for every protocol and peer and the
  bare C and Python write/read floors, all on the same kind of bus;
* turnaround p50/p99/max from the bus capture (end of a request to the
  start of its answer, i.e. the responder's reaction time);
* unpaced exchanges/s and CPU µs per exchange, client and server;
* scale: 1/4/16 buses in one process and 1..31 slaves on one bus: CPU per
  poll cycle, idle CPU of the master, RSS per handle;
* Python overhead: fap_py against the C API (bench/fap_py);
* the network rows (bench/net.py), codec throughput, and the other
  benches' issue-24 rows (G485 paired, bridge, real-time).

Peers that are missing are named with how to get them, and skipped.
Results go to ``$XDG_CACHE_HOME/fap-bench/<date>-<host>/`` (results.json,
table.md, *.png), outside the source tree; ``--out`` puts them elsewhere.

    python -m bench            # full run, about 7 minutes on 2 cores
    python -m bench --quick    # smoke run, under a minute (CI)

The modules: ``kinds`` (what is measured), ``stats`` (statistics, probes of
a process), ``syscalls`` (perf), ``runner`` (the runs and series), ``net``
(network rows), ``report`` (table, plots), ``readme`` (README's section),
``verdicts`` / ``targets`` (the target rows); this file only plans a run.
"""
from __future__ import annotations

import argparse
import datetime
import json
import logging
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional

from bench import ROOT, results_home, syscalls, use_installed_fap_py, verdicts
from bench.kinds import ALL_KINDS, BASE, QUICK_KINDS
from bench.stats import loadavg

log = logging.getLogger("bench")

#: the parts of a run, in order (``--sections``)
SECTIONS = ("paced", "unpaced", "scale", "network", "mismatch", "python", "g485-paired",
            "codec", "parts")
#: the other benches' issue-24 rows not run by --quick (each many seconds)
QUICK_PARTS_WHY = ("not run in --quick (a smoke run); the full `python -m bench` measures it, "
                   "or run the part's own program (bench/README.md)")


def parse(argv: Optional[List[str]]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="python -m bench",
        description="Run every benchmark on the virtual bus; write JSON, a Markdown table and PNG plots.",
        epilog="example: python -m bench --quick --out /tmp/bench-smoke",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run (< 1 min on 2 cores): 115200 only, one short run per cell, "
                         "the project's engines, libmodbus and the floors (no Python peers), "
                         "scale, network, Python overhead and codec rows, none of the other "
                         "benches' issue-24 rows")
    ap.add_argument("--build-dir", type=Path, default=ROOT / "build",
                    help="meson build directory (default: build/ in the repository)")
    ap.add_argument("--rounds", type=int, help="runs per cell (default 3, quick 1)")
    ap.add_argument("--seconds", type=float, help="measuring time per run (default 1.5, quick 0.3)")
    ap.add_argument("--out", type=Path,
                    help=f"result directory (default {results_home()}/<date>-<host>, "
                         "$XDG_CACHE_HOME/fap-bench: outside the source tree)")
    ap.add_argument("--only", help="comma list of kinds to run (default: all available): "
                    + ",".join(ALL_KINDS))
    ap.add_argument("--sections", help="comma list of the parts to run (default: all): "
                    + ",".join(SECTIONS))
    ap.add_argument("--baseline", type=Path, metavar="BUILD_DIR",
                    help="also run the FAP, exec async and mikroC kinds with the bench_wire of "
                         "another build (e.g. of the previous commit), same bus, same run")
    ap.add_argument("--skip-parts", action="store_true",
                    help="leave out the other benches' issue-24 rows (G485, bridge, real-time): "
                         "shown as not measured")
    ap.add_argument("--readme", type=Path, metavar="RESULT_DIR", nargs="?", const=Path("latest"),
                    help="measure nothing: regenerate README.md's benchmark section from a run's "
                         f"results.json (default: the newest run in {results_home()}, else the "
                         "newest bench/results/*)")
    ap.add_argument("--profile", action="store_true",
                    help="only the profile: per exchange and side, CPU, wake-ups and every "
                         "syscall by name (perf), C kinds at 115200 and 1 Mbaud")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="progress on stderr")
    args = ap.parse_args(argv)
    for opt, allowed in (("only", ALL_KINDS), ("sections", SECTIONS)):
        value = getattr(args, opt)
        if value is not None:
            unknown = set(value.split(",")) - set(allowed)
            if unknown:
                ap.error(f"unknown name(s) in --{opt}: {', '.join(sorted(unknown))} "
                         f"(known: {','.join(allowed)})")
    return args


def plan(args: argparse.Namespace) -> Dict[str, str]:
    """The kinds this run leaves out on purpose, with why (not "missing":
    a missing peer is one this run would have measured)."""
    skipped: Dict[str, str] = {}
    for k in ALL_KINDS:
        if args.quick and k not in QUICK_KINDS:
            skipped[k] = "not run in --quick (the full run compares it)"
        elif args.only and k not in args.only.split(","):
            skipped[k] = "not in --only"
    return skipped


def main(argv: Optional[List[str]] = None) -> int:
    args = parse(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="bench: %(message)s")
    if args.readme:
        from bench import readme
        return readme.main(args.readme, ROOT)
    # The checkout's fap_py/ has no compiled _native: the installed fap_py
    # from here on (also in the children: they run in a temp dir).
    use_installed_fap_py()
    from bench import net, report
    from bench import runner as rn

    rn.suite_paths()
    quick = args.quick
    rounds = args.rounds or (1 if quick else 3)
    seconds = args.seconds or (0.3 if quick else 1.5)
    host = socket.gethostname()
    date = datetime.date.today().isoformat()
    out = (args.out or results_home() / f"{date}-{host}").resolve()
    args.build_dir = args.build_dir.resolve()
    runner = rn.Runner(args)
    os.chdir(runner.tmp)
    if not runner.exe.exists():
        print(f"bench: error: {runner.exe} missing: run meson setup build && meson compile -C build",
              file=sys.stderr)
        return 3
    skipped = plan(args)
    kinds, missing = rn.available(runner, [k for k in ALL_KINDS if k not in skipped])
    for k, how in missing.items():
        print(f"bench: peer {k} missing, skipped ({how})", file=sys.stderr)
    left = [k for k, why in skipped.items() if why.startswith("not run in --quick")]
    if left:
        print(f"bench: --quick: not run: {', '.join(left)} (Python peers; the full run "
              "compares them)", file=sys.stderr)
    sections = args.sections.split(",") if args.sections else list(SECTIONS)
    plotting = report.have_matplotlib()
    if not plotting:       # said before the measuring starts, as for a missing peer
        print("bench: matplotlib missing, plots skipped (pip install '.[bench]')", file=sys.stderr)
    if args.baseline:
        args.baseline = args.baseline.resolve()
        at = kinds.index("mikroc") + 1 if "mikroc" in kinds else len(kinds)
        kinds[at:at] = [BASE + k for k in ("fap-poll", "fap-data", "exec", "mikroc") if k in kinds]
    if args.profile:
        if not syscalls.have_perf():
            print("bench: --profile needs perf (apt-get install linux-perf)", file=sys.stderr)
            return 3
        prof = rn.profile(runner, kinds, [115200, 1000000], rounds, seconds)
        out.mkdir(parents=True, exist_ok=True)
        (out / "profile.json").write_text(json.dumps({"loadavg": loadavg(), "profile": prof},
                                                     indent=1))
        print(f"load average {loadavg()}\n\n" + report.profile_markdown(prof))
        return 0
    bauds = [115200] if quick else [9600, 115200, 1000000]
    scale_bauds = [115200] if quick else [115200, 1000000]
    t_start = time.monotonic()
    res: Dict[str, Any] = {
        "date": date, "host": host, "loadavg_before": loadavg(), "rounds": rounds, "seconds": seconds,
        "machine": f"{os.cpu_count()} CPUs, {os.uname().sysname} {os.uname().release} {os.uname().machine}",
        "quick": quick, "bauds": bauds, "missing": missing, "skipped": skipped,
        "sections": sections, "section_s": {}, "paced": {}, "unpaced": {}, "scale": {}}

    def step(name: str, what: str, fn: Callable[[], None]) -> None:
        if name not in sections:
            return
        log.info("%s", what)
        bar.advance(what)
        t0 = time.monotonic()
        fn()
        res["section_s"][name] = res["section_s"].get(name, 0.0) + time.monotonic() - t0

    def paced(baud: int, kind: str) -> None:
        res["paced"].setdefault(str(baud), {})[kind] = rn.measure_series(
            runner, kind, baud, rounds, seconds if baud > 9600 else seconds * 2)

    def unpaced(kind: str) -> None:
        res["unpaced"][kind] = rn.measure_series(runner, kind, 0, rounds, seconds)

    def scale(baud: int) -> None:
        res["scale"][str(baud)] = rn.scale_series(runner, baud, 1 if quick else 2, seconds, quick)

    def network() -> None:
        if net.have_ser2net():
            res["network"] = {"baud": 115200,
                              "rows": net.network_series(runner, 115200, rounds, seconds, quick)}
        else:
            print("bench: ser2net missing, network rows skipped (apt-get install ser2net)",
                  file=sys.stderr)

    def mismatch() -> None:
        res["mismatch"] = net.mismatch_series(runner, rounds, seconds, quick)

    def python() -> None:
        try:
            res["python"] = rn.python_overhead(args, quick)
        except Exception as e:
            log.warning("python overhead: %s", e)

    g485_rows: Dict[str, List[Any]] = {}

    def g485_paired() -> None:
        try:
            import paired as g485_paired  # bench/g485/paired.py
            res["g485_paired"] = {}
            rows = g485_paired.targets([b for b in bauds if b >= 115200], rounds=3 if quick else 21,
                                       results=res["g485_paired"])
            res["g485_targets"] = [t.as_dict() for t in rows]
            if quick:   # the issue-24 G485 rows of this run: not measured a second time
                g485_rows["bench.g485.paired"] = rows
        except Exception as e:
            log.warning("g485 paired: %s", e)

    def codec() -> None:
        try:
            res["codec"] = rn.codec_throughput(runner, 0.05 if quick else 0.3)
        except Exception as e:
            log.warning("codec throughput: %s", e)

    parts: List[Any] = []

    def other_parts() -> None:
        if quick:
            print("bench: --quick: not run: the bridge and real-time issue-24 rows (shown as not "
                  "measured; the full run measures them)", file=sys.stderr)
        parts.extend(verdicts.part_rows(rounds, quick, skip=args.skip_parts or quick,
                                       why=QUICK_PARTS_WHY if quick and not args.skip_parts
                                       else "skipped (--skip-parts)",
                                       measured=g485_rows))

    # one step per measured cell; a rich bar on a terminal (stderr), nothing otherwise
    steps = (("paced" in sections) * len(bauds) * len(kinds) + ("unpaced" in sections) * len(kinds)
             + ("scale" in sections) * len(scale_bauds)
             + sum(s in sections for s in SECTIONS[3:]))
    from fap_py.progress import Progress  # the installed fap_py (use_installed_fap_py, in main)

    with Progress(steps, "bench", enabled=True) as bar:
        for baud in bauds:
            for kind in kinds:
                step("paced", f"paced {baud}: {kind}", lambda: paced(baud, kind))
        for kind in kinds:
            step("unpaced", f"unpaced: {kind}", lambda: unpaced(kind))
        for baud in scale_bauds:
            step("scale", f"scale at {baud}", lambda: scale(baud))
        step("network", "network transports", network)
        step("mismatch", "mismatched baud", mismatch)
        step("python", "Python overhead", python)
        if "g485" in kinds:
            step("g485-paired", "G485 paired", g485_paired)
        step("codec", "codec throughput", codec)
        step("parts", "issue-24 parts", other_parts)
    res["targets"] = [t.as_dict() for t in verdicts.own_rows(res) + parts]
    res["loadavg_after"] = loadavg()
    res["wall_s"] = time.monotonic() - t_start
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(res, indent=1))
    table = report.markdown(res)
    (out / "table.md").write_text(table + "\n")
    made = report.plots(res, out) if plotting else []
    print(table)
    print(f"\nbench: wrote {out}/results.json, table.md"
          + (f", {', '.join(made)}" if made else " (no plots: matplotlib missing)")
          + f" in {res['wall_s']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
