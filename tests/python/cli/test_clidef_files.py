"""Issue 33 item 11: an empty file is no capture (one line, exit 3), while a
header-only capture of a quiet bus is read (0 frames, exit 0); the project's
address is one value: pyproject.toml's URLs, the Wireshark extcap help
(through the launcher `fap monitor --extcap-dir` writes) and the MQTT
discovery payload's support_url all come from fap_py._project.PROJECT_URL."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from fap_py._project import PROJECT_URL

from .conftest import run_proc

ROOT = Path(__file__).resolve().parents[3]


def test_empty_file_is_not_a_capture(tmp_path: Path) -> None:
    empty = tmp_path / "empty.cap"
    empty.write_bytes(b"")
    for extra in ((), ("--json",), ("--stats",)):
        res = run_proc("monitor", "--capture", str(empty), *extra)
        assert res.code == 3, res
        assert res.err == (f"fap: error: {empty}: empty file: not a capture (no "
                           "'# fap-vbus-capture' header, no data line)\n")
        assert res.out == ""
    blank = tmp_path / "blank.cap"
    blank.write_text("\n  \n")
    assert run_proc("monitor", "--capture", str(blank)).code == 3
    quiet = tmp_path / "quiet.cap"
    quiet.write_text("# fap-vbus-capture 1 ports=2 baud=9600 echo=0 seed=0\n")
    res = run_proc("monitor", "--capture", str(quiet), "--stats")
    assert res.code == 0 and res.out.startswith("-- 0 frames"), res


def test_project_url_is_one_value(tmp_path: Path) -> None:
    import tomllib

    urls = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["urls"]
    assert urls["Homepage"] == urls["Repository"] == PROJECT_URL
    assert all(u == PROJECT_URL or u.startswith(PROJECT_URL + "/") for u in urls.values()), urls

    res = run_proc("monitor", "--extcap-dir", str(tmp_path))
    assert res.code == 0, res
    (launcher,) = [p for p in tmp_path.iterdir() if p.is_file()]
    out = subprocess.run([str(launcher), "--extcap-interfaces"], capture_output=True, text=True,
                         timeout=60).stdout
    assert f"{{help={PROJECT_URL}/blob/main/docs/monitor.md}}" in out, out

    code = ("import json; from fap_py.bridge import homeassistant as h; "
            "print(h._ORIGIN['support_url'])")
    url = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60).stdout.strip()
    assert url == f"{PROJECT_URL}/blob/main/docs/bridge.md"
