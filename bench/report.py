"""The report of one ``python -m bench`` run: the Markdown table (``table.md``,
also the source of README.md's section, :mod:`bench.readme`), the profile
table and the PNG plots (matplotlib, optional).

Reads only a run's results (the dict written as ``results.json``); imports
the kinds, the targets and the network rows' formatter, never the runner.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Optional

from bench import net
from bench.kinds import BASE, PY_KINDS, floor_of, floor_rate, label
from bench.targets import Target, table


def profile_markdown(prof: Dict[str, Any]) -> str:
    L = ["| exchange | side | CPU µs | wake-ups | syscalls | by syscall (per exchange) |",
         "|---|---|---|---|---|---|"]
    for key, row in prof.items():
        kind, baud = key.split("@")
        for side in ("client", "server"):
            by = row[side]
            total = by.get("syscalls", 0.0)
            names = sorted(((v, n) for n, v in by.items() if n != "syscalls" and v >= 0.05),
                           reverse=True)
            L.append(f"| {label(kind)} @ {baud} | {side} | {row[side + '_us']:.0f} | "
                     f"{row[side + '_wakeups']:.1f} | {total:.1f} | "
                     + ", ".join(f"{n} {v:.2g}" for v, n in names) + " |")
    return "\n".join(L) + "\n"


def fmt(s: Dict[str, float], f: str = "{:.0f}") -> str:
    return f"{f.format(s['median'])} ({f.format(s['min'])}–{f.format(s['max'])})"


def targets(res: Dict[str, Any]) -> List[str]:
    """Issue 16's targets, each checked against this run (a report, not an assertion)."""
    L = ["## Earlier targets (issue 16) in this run", ""]

    def line(ok: Optional[bool], text: str) -> None:
        L.append(f"- {'met' if ok else 'MISSED' if ok is not None else 'n/a'}: {text}")

    for baud in ("115200", "1000000"):
        rows = res["paced"].get(baud, {})
        for kind in ("fap-poll", "exec", "mikroc"):   # G485: the paired rows below (bench/g485/paired.py)
            r = rows.get(kind)
            fr = floor_rate(kind, int(baud), rows) if r and "rate" in r else None
            if fr:
                share = 100 * r["rate"]["median"] / fr
                line(share >= 97, f"{label(kind)} at {baud}: {share:.1f} % of the floor's efficiency (target 97 %)")
        mb = rows.get("modbus")
        for kind in ("fap-poll", "exec", "mikroc"):
            r = rows.get(kind)
            if r and mb and "client_us" in r and "client_us" in mb:
                c, m = r["client_us"]["median"], mb["client_us"]["median"]
                line(c <= m / 2, f"{label(kind)} at {baud}: client CPU {c:.0f} µs/exchange vs libmodbus {m:.0f} (target ≤ half)")
            b = rows.get(BASE + kind)
            if r and b and r.get("turnaround_us") and b.get("turnaround_us"):
                n, o = r["turnaround_us"]["p50"], b["turnaround_us"]["p50"]
                line(n <= o * 1.1, f"{label(kind)} at {baud}: turnaround p50 {n:.0f} µs vs {o:.0f} µs before (target no worse)")
    sc = res.get("scale", {}).get("115200")
    if sc:
        one = {str(k): v for k, v in sc["buses"].items()}["1"]
        load = 100 * one["master_load"]["median"]
        line(load < 2, f"idle FAP master at 115200: {load:.2f} % of a core (target < 2 %)")
    for baud, sc in res.get("scale", {}).items():
        b = {str(k): v for k, v in sc["buses"].items()}
        if "1" in b and "16" in b:
            a, z = b["1"]["cpu_us_per_cycle"]["median"], b["16"]["cpu_us_per_cycle"]["median"]
            line(z <= 1.2 * a, f"CPU per poll cycle at {baud}, 1 → 16 buses: {a:.1f} → {z:.1f} µs "
                               "(target flat: at most 20 % above 1 bus)")
        most = max(b, key=int)            # many handles: the process's own first-use pages shared out
        rss = b[most]["rss_kib_per_handle"]["median"]
        line(rss < 256, f"RSS per FAP handle at {baud}: {rss:.0f} KiB with {most} handles in one process "
                        f"({b['1']['rss_kib_per_handle']['median']:.0f} KiB for the first) (target < 256 KiB)")
    L.append("")
    if res.get("g485_targets"):   # G485 vs the bare Python floor: paired rounds (bench/g485/paired.py)
        L += ["## G485 targets (issue 24): paired rounds, paced", "",
              table([Target(**{k: v for k, v in t.items() if k != "met"}) for t in res["g485_targets"]]), ""]
    return L


def markdown(res: Dict[str, Any]) -> str:
    L = [f"# Benchmark {res['date']} on {res['host']}", "",
         f"{res['machine']}; load average before/after: {res['loadavg_before']} / "
         f"{res['loadavg_after']}; rounds {res['rounds']}, {res['seconds']} s each; "
         "median (min–max).", "",
         "Efficiency: exchanges/s as a share of the framing limit (10 bits per byte, request + "
         "reply bytes; Modbus's 3.5-character silence not counted, the peers do not keep it on a pty). vs floor: exchanges/s against what the bare "
         "write/read floor (C for the C engines, Python for the Python libraries) reaches with the "
         "same frame sizes (their wire time plus the floor's measured per-exchange overhead). "
         "Wake-ups/x: voluntary context switches per exchange (C sides only; does not "
         "depend on the machine's load as CPU time does). "
         "Turnaround: end of a request to the start of its answer, from the bus capture.", ""]
    if res["missing"]:
        L += ["Missing peers (skipped): " + "; ".join(f"{k}: {v}" for k, v in res["missing"].items()), ""]
    if res.get("skipped"):
        L += ["Not run in this mode: " + "; ".join(f"{k}: {v}" for k, v in res["skipped"].items()), ""]
    for baud in res["bauds"]:
        rows = res["paced"].get(str(baud))
        if not rows:
            continue
        L += [f"## Paced at {baud} baud", "",
              "| protocol / peer | exchanges/s | framing limit/s | efficiency | vs floor | "
              "client µs/x | server µs/x | wake-ups/x client, server | syscalls/x client, server | "
              "turnaround p50 / p99 / max µs |",
              "|---|---|---|---|---|---|---|---|---|---|"]
        for kind, r in rows.items():
            if "error" in r:
                L.append(f"| {label(kind)} | failed | | | | | | | | |")
                continue
            fr = floor_rate(kind, baud, rows)
            vs = f"{100 * r['rate']['median'] / fr:.1f} %" if fr else ""
            ta = r.get("turnaround_us")
            tas = f"{ta['p50']:.0f} / {ta['p99']:.0f} / {ta['max']:.0f}" if ta else ""
            wk = (f"{r['client_wakeups']['median']:.1f}, {r['server_wakeups']['median']:.1f}"
                  if "client_wakeups" in r else "")
            sc = (f"{r['client_syscalls']['median']:.1f}, {r['server_syscalls']['median']:.1f}"
                  if "client_syscalls" in r and "server_syscalls" in r else "")
            L.append(f"| {label(kind)} | {fmt(r['rate'])} | {r['limit']:.0f} | "
                     f"{fmt({k: 100 * v for k, v in r['efficiency'].items()}, '{:.1f}')} % | {vs} | "
                     f"{fmt(r['client_us'])} | {fmt(r['server_us'])} | {wk} | {sc} | {tas} |")
        L.append("")
    if res.get("unpaced"):
        L += ["## Unpaced (as fast as the ptys go)", "",
              "| protocol / peer | exchanges/s | client µs/x | server µs/x |", "|---|---|---|---|"]
        for kind, r in res["unpaced"].items():
            if "error" not in r:
                L.append(f"| {label(kind)} | {fmt(r['rate'])} | {fmt(r['client_us'])} | {fmt(r['server_us'])} |")
        L.append("")
    for baud, sc in res.get("scale", {}).items():
        L += [f"## Scale: FAP master, paced at {baud} baud (slaves with nothing to send)", "",
              "| buses in one process | poll cycles/s | master CPU µs/cycle | master load | RSS KiB/handle |",
              "|---|---|---|---|---|"]
        for n, r in sc["buses"].items():
            L.append(f"| {n} | {fmt(r['cycles_per_s'])} | {fmt(r['cpu_us_per_cycle'], '{:.1f}')} | "
                     f"{fmt({k: 100 * v for k, v in r['master_load'].items()}, '{:.2f}')} % | "
                     f"{fmt(r['rss_kib_per_handle'])} |")
        L += ["", "| slaves on one bus | poll cycles/s | master CPU µs/cycle | master load |", "|---|---|---|---|"]
        for n, r in sc["slaves"].items():
            L.append(f"| {n} | {fmt(r['cycles_per_s'])} | {fmt(r['cpu_us_per_cycle'], '{:.1f}')} | "
                     f"{fmt({k: 100 * v for k, v in r['master_load'].items()}, '{:.2f}')} % |")
        L.append("")
    if res.get("python"):
        L += ["## Python overhead (fap_py vs C API, unpaced, 16-byte messages)", "",
              "| mode | C msgs/s | Python msgs/s | C CPU µs/msg | Python CPU µs/msg |", "|---|---|---|---|---|"]
        for mode, r in res["python"].items():
            L.append(f"| {mode} | {r.get('c_rate', float('nan')):.0f} | {r['py_rate']:.0f} | "
                     f"{r.get('c_cpu_us', float('nan')):.1f} | {r['py_cpu_us']:.1f} |")
        L.append("")
    L += ["## Targets in this run", "",
          "Medians of the run's rounds; CPU ratios: this engine's CPU µs per exchange over "
          "libmodbus's read, the same side, the same run. Load average before/after: "
          f"{res['loadavg_before']} / {res.get('loadavg_after', '?')}.", "",
          table([Target(**{k: v for k, v in t.items() if k != "met"})
                 for t in res.get("targets", [])])]
    L += targets(res)
    if res.get("codec"):
        c, p = res["codec"]["c"], res["codec"]["python"]
        L += ["## Codec throughput (payload MB/s, no I/O)", "",
              "| codec | C encode | C decode | Python encode | Python decode |", "|---|---|---|---|---|"]
        for name, cname in (("FAP (1024-byte DATA)", "fap"), ("exec async (255 bytes)", "exec"),
                            ("mikroC (3 bytes)", "mikroc"), ("G485 (32-byte write)", "g485")):
            def g(d: Dict[str, float], k: str) -> str:
                return f"{d[k]:.2f}" if k in d else "—"
            L.append(f"| {name} | {g(c, cname + '_encode')} | {g(c, cname + '_decode')} | "
                     f"{g(p, cname + '_encode')} | {g(p, cname + '_decode')} |")
        L += ["", "FAP has no Python codec (fap_py drives the C engine); G485 is pure Python.", ""]
    L += net.markdown_lines(res)   # ser2net rows and the mismatched-baud case
    return "\n".join(L)


def have_matplotlib() -> bool:
    """Plots need matplotlib (``pip install '.[bench]'``); the measurements do not."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    return True


def plots(res: Dict[str, Any], out: Path) -> List[str]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    made = []
    bauds = [b for b in res["bauds"] if res["paced"].get(str(b))]
    if not bauds:
        return made
    kinds = list(res["paced"][str(bauds[0])])
    # 1. efficiency vs baud
    fig, ax = plt.subplots(figsize=(9, 5.5))
    colors = iter(plt.get_cmap("tab20").colors[::2] + plt.get_cmap("tab20").colors[1::2])
    for kind in kinds:
        pts = [(b, res["paced"][str(b)][kind]["efficiency"]) for b in bauds
               if "efficiency" in res["paced"][str(b)].get(kind, {})]
        if not pts:
            continue
        floor = floor_of(kind) is None
        python = kind in PY_KINDS
        xs = [b * (1.03 if python else 1) for b, _ in pts]   # side by side, not on top
        ys = [100 * e["median"] for _, e in pts]
        err = [[100 * (e["median"] - e["min"]) for _, e in pts], [100 * (e["max"] - e["median"]) for _, e in pts]]
        ax.errorbar(xs, ys, yerr=err, fmt="--" if floor else "-", marker="s" if python else "o",
                    color="black" if floor and not python else "grey" if floor else next(colors),
                    capsize=3, label=label(kind) + (" (Python)" if python and not floor else ""))
    ax.set_xscale("log")
    ax.set_xticks(bauds, [f"{b:,}" for b in bauds])
    ax.set_ylim(0, 105)
    ax.set_xlabel("baud (paced virtual bus)")
    ax.set_ylabel("exchanges/s as % of the framing limit")
    ax.set_title(f"Efficiency vs baud rate ({res['host']}, {res['date']}; median, bars min–max)")
    ax.grid(True, which="both", alpha=.3)
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "efficiency.png", dpi=90)
    plt.close(fig)
    made.append("efficiency.png")
    # 2. turnaround distributions at 115200 (or the middle baud)
    b = str(115200 if 115200 in bauds else bauds[0])
    data = [(label(k), res["paced"][b][k]["turnaround_sample"]) for k in kinds
            if res["paced"][b].get(k, {}).get("turnaround_sample")]
    if data:
        fig, ax = plt.subplots(figsize=(9, 5.5))
        ax.boxplot([d for _, d in data], orientation="horizontal", whis=(1, 99), showfliers=False)
        ax.set_yticks(range(1, len(data) + 1), [n for n, _ in data], fontsize=8)
        ax.set_xscale("log")
        ax.set_xlabel("responder turnaround µs (end of request to start of answer; whiskers p1–p99)")
        ax.set_title(f"Turnaround from the bus capture, paced at {b} baud")
        ax.grid(True, axis="x", which="both", alpha=.3)
        fig.tight_layout()
        fig.savefig(out / "turnaround.png", dpi=90)
        plt.close(fig)
        made.append("turnaround.png")
    # 3. CPU per exchange (client and server) at each baud and unpaced
    cols = [str(x) for x in bauds] + (["unpaced"] if res.get("unpaced") else [])
    fig, axes_ = plt.subplots(1, len(cols), figsize=(4 * len(cols), 5.5), sharey=True, squeeze=False)
    axes = axes_[0]
    for ax, col in zip(axes, cols):
        rows = res["unpaced"] if col == "unpaced" else res["paced"][col]
        ks = [k for k in kinds if k in rows and "client_us" in rows[k]]
        y = range(len(ks))
        ax.barh([i - .2 for i in y], [rows[k]["client_us"]["median"] for k in ks], .4, label="client")
        ax.barh([i + .2 for i in y], [rows[k]["server_us"]["median"] for k in ks], .4, label="server")
        for i, k in zip(y, ks):           # the numbers: busy-waiting peers span 3 decades
            ax.text(rows[k]["client_us"]["median"] * 1.1, i - .2, f"{rows[k]['client_us']['median']:.0f}",
                    va="center", fontsize=7)
        ax.set_yticks(list(y), [label(k) for k in ks], fontsize=8)
        ax.set_xscale("log")
        ax.set_xlim(1, 30000)                 # every bar starts at 1 µs: lengths compare
        ax.set_title(f"{col}{' baud' if col != 'unpaced' else ''}")
        ax.set_xlabel("CPU µs per exchange (log)")
        ax.grid(True, axis="x", which="both", alpha=.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("CPU per exchange (lower is better)")
    fig.tight_layout()
    fig.savefig(out / "cpu.png", dpi=90)
    plt.close(fig)
    made.append("cpu.png")
    # 4. scaling
    if not res.get("scale"):
        return made
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for baud, sc in res["scale"].items():
        xs = sorted(int(n) for n in sc["buses"])
        a1.plot(xs, [sc["buses"][n]["cpu_us_per_cycle"]["median"] for n in sc["buses"]], marker="o",
                label=f"{baud} baud")
        xs2 = [int(n) for n in sc["slaves"]]
        a2.plot(xs2, [100 * sc["slaves"][n]["master_load"]["median"] for n in sc["slaves"]], marker="o",
                label=f"{baud} baud")
    a1.set_xscale("log", base=2)
    xs_all = sorted({int(n) for sc in res["scale"].values() for n in sc["buses"]})
    a1.set_xticks(xs_all, [str(x) for x in xs_all])
    a1.set_xlabel("buses (one FAP master each) in one process")
    a1.set_ylabel("master CPU µs per poll cycle")
    a1.set_ylim(bottom=0)
    a2.set_xlabel("slaves on one bus (nothing to send)")
    a2.set_ylabel("idle master CPU, % of a core")
    a2.set_ylim(bottom=0)
    for a in (a1, a2):
        a.grid(True, alpha=.3)
        a.legend(fontsize=8)
    fig.suptitle("FAP master scaling on a paced bus")
    fig.tight_layout()
    fig.savefig(out / "scaling.png", dpi=90)
    plt.close(fig)
    made.append("scaling.png")
    return made


