"""`fap monitor --port fapd://...`: a passive tap on every frame the daemon sends and
receives, decoded by the monitor as on a live port (sender 0 the daemon, 1 a slave)."""
from __future__ import annotations

import json
import subprocess

from serve_helpers import fap_cmd

from fap_py.execasync import Master


def test_monitor_taps_the_daemons_frames(served, vbus):
    mon = subprocess.Popen(fap_cmd("monitor", "--protocol", "exec", "--port", served.url,
                                   "--idle", "1", "--json"),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert "listening on fapd://" in mon.stderr.readline()    # from now on it sees frames
        served.wait_for(lambda st: any(c["monitor"] for c in st["clients"]))
        with Master(served.url, timeout=0.2) as m:
            for i in range(3):
                assert m.transact(5, bytes([i])) == bytes([i])
        out, err = mon.communicate(timeout=30)
    finally:
        mon.kill()
    assert mon.returncode == 0, err
    frames = [o for o in map(json.loads, out.splitlines()) if o["event"] == "frame"]
    assert [(f["port"], f["node"], f["seq"], f["data"]) for f in frames] == [
        (p, 5, i, f"{i:02x}") for i in range(3) for p in (0, 1)]
    assert all(f["ok"] and f["t"] > 0 for f in frames)
