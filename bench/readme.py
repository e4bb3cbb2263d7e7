"""``python -m bench --readme [RESULT_DIR]``: README.md's benchmark section from a run.

The section between the markers ``<!-- bench:begin -->`` and ``<!-- bench:end
-->`` in the top-level README.md is rewritten from one run's ``results.json``
(by default the newest run in :func:`bench.results_home`, else the newest
baseline in ``bench/results/``): the run's setup and load, the met/missed
table of issue 24's targets, and the paced 115200 and 1 Mbaud tables.
Nothing is measured; the lead regenerates the section after a run. A run
inside the repository is linked; one outside it (the default place) is
named by its folder, since readers of the README cannot open it.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Dict, List, Optional

from bench import results_home, verdicts
from bench.report import markdown  # the runner's own tables, one format
from bench.targets import Target, table

BEGIN = "<!-- bench:begin -->"
END = "<!-- bench:end -->"


def _full(run: Path) -> bool:
    try:
        return not json.loads((run / "results.json").read_text()).get("quick")
    except (OSError, ValueError):
        return False


def newest(results: Path) -> Path:
    """The newest full run (not a --quick smoke run) under ``results``."""
    runs = sorted((p for p in (results.iterdir() if results.is_dir() else ())
                   if (p / "results.json").is_file() and _full(p)),
                  key=lambda p: (p / "results.json").stat().st_mtime)
    if not runs:
        raise FileNotFoundError(f"no full run with results.json under {results}")
    return runs[-1]


def section(res: Dict[str, Any], rel: Optional[str], plots: bool = False) -> str:
    """The generated Markdown (no markers); ``rel``: the run's folder relative
    to the repository, None for a run outside it."""
    full = markdown(res)
    blocks = full.split("\n## ")
    keep = [b for b in blocks if b.startswith(("Paced at 115200", "Paced at 1000000"))]
    rows = ([Target(**{k: v for k, v in t.items() if k != "met"}) for t in res["targets"]]
            if "targets" in res else verdicts.own_rows(res))     # a run from before the rows
    met = sum(1 for t in rows if t.met)
    missed = sum(1 for t in rows if t.met is False)
    L: List[str] = [
        f"Latest run: {res['date']} on `{res['host']}`, {res['machine']}; load average "
        f"{res['loadavg_before']} before, {res.get('loadavg_after', '?')} after; "
        f"{res['rounds']} rounds of {res['seconds']} s, medians (min–max). "
        + (f"Full table and plots: [`{rel}/table.md`]({rel}/table.md)." if rel else
           "Full table and plots: the run's `table.md` and PNGs (kept outside the repository)."),
        "",
        f"Targets in this run: {met} met, {missed} missed, "
        f"{len(rows) - met - missed} not measured.", "",
        table(rows)]
    if plots and rel:
        L += [f"![efficiency vs baud]({rel}/efficiency.png)", ""]
    for b in keep:
        title, _, body = b.partition("\n")
        L += [f"{title.strip()}:", "", body.strip(), ""]
    return "\n".join(L).rstrip() + "\n"


def regenerate(readme: Path, run: Path, root: Path) -> None:
    res = json.loads((run / "results.json").read_text())
    if res.get("quick"):
        raise ValueError(f"{run} is a --quick smoke run, not a measurement: "
                         "regenerate from a full `python -m bench` run")
    rel: Optional[str]
    try:
        rel = str(run.resolve().relative_to(root.resolve()))
    except ValueError:
        rel = None
    text = readme.read_text()
    if BEGIN not in text or END not in text:
        raise ValueError(f"{readme}: markers {BEGIN} / {END} missing")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    plots = (run / "efficiency.png").is_file()
    readme.write_text(head + BEGIN + "\n" + section(res, rel, plots) + END + tail)


def main(run: Path, root: Path) -> int:
    try:
        if str(run) == "latest":
            try:
                run = newest(results_home())
            except FileNotFoundError:
                run = newest(root / "bench" / "results")   # the baselines kept in git
        regenerate(root / "README.md", run, root)
    except (OSError, ValueError, KeyError, json.JSONDecodeError) as e:
        print(f"bench: --readme: {e}", file=sys.stderr)
        return 3
    print(f"bench: README.md benchmark section regenerated from {run}")
    return 0
