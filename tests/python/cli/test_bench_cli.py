"""``python -m bench``'s user-visible behaviour (issue 32, item 2), with tiny runs:
results outside the source tree by default, nothing added to git, ``--readme``
pointed at a run directory, perf's window notes filtered, and the Python peers
that --quick does not run said as "not run", never as "missing"."""
from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Iterator

import pytest

from .test_progress import ROOT, _build_dir


@pytest.fixture
def bench_path() -> Iterator[None]:
    saved = list(sys.path)
    sys.path.insert(0, str(ROOT))
    try:
        yield
    finally:
        sys.path[:] = saved


def _git_status() -> str:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        return ""
    # bench/ only: where the old default put runs (the rest of a checkout may be edited meanwhile)
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all", "--", "bench"],
                          cwd=ROOT, capture_output=True, text=True, timeout=30).stdout


def test_bench_writes_outside_the_tree_by_default(tmp_path: Path) -> None:
    build = _build_dir()
    if build is None:
        if os.environ.get("CI"):
            pytest.fail("no meson build directory with bench/ for python -m bench")
        pytest.skip("no meson build directory")
    before = _git_status()
    code = ("import runpy, sys; sys.modules['matplotlib'] = None; sys.modules['pytest'] = None; "
            "runpy.run_module('bench', run_name='__main__', alter_sys=True)")
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    p = subprocess.run([sys.executable, "-c", code, "--quick", "--only", "fap-poll", "--sections",
                        "paced", "--seconds", "0.1", "--build-dir", str(build)],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=40)
    assert p.returncode == 0, p.stderr
    runs = list((tmp_path / "cache" / "fap-bench").iterdir())
    assert len(runs) == 1 and (runs[0] / "results.json").is_file(), runs
    assert f"bench: wrote {runs[0]}/results.json" in p.stdout
    assert "Events disabled" not in p.stderr and "Events enabled" not in p.stderr
    assert _git_status() == before           # the run added nothing to the checkout
    res = json.loads((runs[0] / "results.json").read_text())
    assert "rate" in res["paced"]["115200"]["fap-poll"]


def test_readme_from_a_run_directory_outside_the_repository(tmp_path: Path, bench_path: None) -> None:
    from bench import readme

    root, run = tmp_path / "repo", tmp_path / "elsewhere" / "2026-12-02-h"
    root.mkdir()
    run.mkdir(parents=True)
    (root / "README.md").write_text(f"# x\n{readme.BEGIN}\nold\n{readme.END}\n")
    res = {"date": "2026-12-02", "host": "h", "machine": "2 CPUs", "loadavg_before": "1 1 1",
           "loadavg_after": "1 1 1", "rounds": 1, "seconds": 0.3, "bauds": [115200],
           "missing": {}, "paced": {"115200": {}}, "unpaced": {}, "scale": {}, "targets": []}
    (run / "results.json").write_text(json.dumps(res))
    (run / "efficiency.png").write_bytes(b"png")
    assert readme.main(run, root) == 0
    text = (root / "README.md").read_text()
    assert "old" not in text and "Latest run: 2026-12-02 on `h`" in text
    assert "kept outside the repository" in text and str(tmp_path) not in text   # no local path
    assert readme.main(tmp_path / "nowhere", root) == 3                         # a clear error
    res["quick"] = True                     # a smoke run's numbers are no measurement
    (run / "results.json").write_text(json.dumps(res))
    assert readme.main(run, root) == 3 and "Latest run: 2026-12-02" in (root / "README.md").read_text()


def test_perf_window_notes_are_filtered_and_real_lines_kept(bench_path: None) -> None:
    from bench import syscalls

    probe = syscalls.Probe()
    probe._err = tempfile.TemporaryFile()     # what perf and the program wrote (perf or not)
    probe._err.write(b"Events disabled\nEvents enabled\nbench_wire: /dev/x: open failed\n"
                     b"Events disabled\nperf: failed to open tracepoint\n")
    got = io.StringIO()
    probe.relay_stderr(got)
    assert got.getvalue() == "bench_wire: /dev/x: open failed\nperf: failed to open tracepoint\n"
    probe.relay_stderr(got)                   # once
    assert probe.result() is None or isinstance(probe.result(), dict)


def test_quick_does_not_call_the_peers_it_does_not_run_missing(bench_path: None, monkeypatch) -> None:
    import importlib.util

    from bench import __main__ as bm
    from bench import runner as rn

    args = bm.parse(["--quick"])
    skipped = bm.plan(args)
    assert set(skipped) == {"minimalmodbus", "pymodbus", "dynamixel"}
    assert all(w.startswith("not run in --quick") for w in skipped.values())
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("pymodbus", "minimalmodbus", "dynamixel_sdk")
                        else real(name, *a))
    fake = argparse.Namespace(exe=Path("/nonexistent/bench_wire"))
    kinds, missing = rn.available(fake, ["bare", "g485"])        # no peer wanted: none missing
    assert kinds == ["bare", "g485"] and missing == {}
    kinds, missing = rn.available(fake, ["bare", "pymodbus"])    # the full run wants it
    assert kinds == ["bare"] and set(missing) == {"pymodbus"} and "pip install" in missing["pymodbus"]
    with pytest.raises(SystemExit):
        bm.parse(["--sections", "paced,nonsense"])


def test_readme_default_is_the_newest_full_run(tmp_path: Path, bench_path: None, monkeypatch) -> None:
    from bench import readme

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    home = tmp_path / "fap-bench"
    for name, quick in (("full", False), ("smoke", True)):      # the smoke run is the newer
        (home / name).mkdir(parents=True)
        (home / name / "results.json").write_text(json.dumps({"quick": quick}))
    assert readme.newest(home).name == "full"
    with pytest.raises(FileNotFoundError):
        readme.newest(tmp_path / "none")
