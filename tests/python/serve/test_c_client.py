"""examples/serve/fapd_client.c, the C client of docs/daemon.md, built here with the
system's C compiler and run against a daemon: the protocol is speakable without fap_py."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

SOURCE = Path(__file__).resolve().parents[3] / "examples" / "serve" / "fapd_client.c"


@pytest.fixture(scope="module")
def client(tmp_path_factory) -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        if os.environ.get("CI"):
            pytest.fail("no C compiler (cc) in CI")
        pytest.skip("no C compiler (cc)")
    exe = str(tmp_path_factory.mktemp("fapd_client") / "fapd_client")
    r = subprocess.run([cc, "-std=c11", "-Wall", "-Wextra", "-Werror", "-o", exe, str(SOURCE)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return exe


def test_the_c_client_transacts_through_the_daemon(client, served, vbus):
    r = subprocess.run([client, served.url, "5", "0a0b0c"], capture_output=True, text=True, timeout=30)
    assert (r.returncode, r.stdout) == (0, "node 5: 0a0b0c\n"), r.stderr
    r = subprocess.run([client, served.url, "9", "01"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 1 and "NoReplyError" in r.stdout
    assert served.status()["totals"]["transactions"] == 2


def test_the_c_client_without_a_daemon_exits_3(client, tmp_path):
    r = subprocess.run([client, f"fapd://{tmp_path}/none.sock", "5", "01"], capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 3 and "no daemon" in r.stderr
