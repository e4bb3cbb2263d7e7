"""``fap web`` as a command: a real run on a capture (ready line, the API, SIGTERM with the
summary), the usage errors (no source, two sources, a public address without a token), a
missing aiohttp named with its extra, an unreadable capture (exit 3), and the library's
access rules."""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys

import pytest
from web_helpers import WAIT_S, get, get_json

from fap_py import execasync

pytest.importorskip("aiohttp")


def write_capture(path, frames=20) -> int:
    """A virtual-bus capture of exec requests (port 0) and replies (port 1); its frame count."""
    lines = ["# fap-vbus-capture 1 ports=2 baud=115200"]
    t = 0
    for i in range(frames // 2):
        for port in (0, 1):
            lines.append(f"{t} {port} " + execasync.encode(3, b"\x01", 1 + i).hex(" "))
            t += 2000
    path.write_text("\n".join(lines) + "\n")
    return frames


def fap(*args: str, env=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fap_py", *args], capture_output=True, text=True,
                          timeout=30, env=env)


def test_serves_a_capture_until_sigterm_with_its_summary(tmp_path):
    cap = tmp_path / "b.cap"
    n = write_capture(cap)
    p = subprocess.Popen([sys.executable, "-m", "fap_py", "web", "--http", "127.0.0.1:0", "--capture", str(cap),
                          "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert select.select([p.stdout], [], [], WAIT_S)[0], "no ready line"
        first = json.loads(p.stdout.readline())
        assert first["event"] == "ready" and first["source"]["kind"] == "capture"
        url = first["url"]
        info = get_json(url + "api/info")
        assert info["kind"] == "capture" and info["seekable"] is True
        status, page = get(url)
        assert status == 200 and b"<canvas" in page
        for name in ("app.js", "style.css"):
            assert get(url + "static/" + name)[0] == 200
        assert get(url + "static/../__init__.py")[0] == 404
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=WAIT_S)
    finally:
        p.kill()
    assert p.returncode == 0, err
    last = json.loads(out.decode().splitlines()[-1])
    assert last == {"event": "stopped", "frames": n, "bad": 0, "collisions": 0, "dropped": 0,
                    "source_error": None}


def test_usage_errors(tmp_path):
    cap = tmp_path / "b.cap"
    write_capture(cap)
    r = fap("web")
    assert r.returncode == 2 and "give one source" in r.stderr
    r = fap("web", "--capture", str(cap), "--port", "/dev/null")
    assert r.returncode == 2 and "--port and --capture" in r.stderr
    r = fap("web", "--http", "0.0.0.0:0", "--capture", str(cap))
    assert r.returncode == 2 and "needs a token" in r.stderr
    r = fap("web", "--http", "nope", "--capture", str(cap))
    assert r.returncode == 2 and "HOST:PORT" in r.stderr
    r = fap("web", "--bus", "x", "--capture", str(cap))
    assert r.returncode == 2 and "--bus needs --sim or --mqtt" in r.stderr
    r = fap("web", "--sim", f"unix:{tmp_path}/s.sock")
    assert r.returncode == 2 and "--tap" in r.stderr
    r = fap("web", "--http", "127.0.0.1:0", "--sim", f"unix:{tmp_path}/s.sock", "--tap", str(cap))
    assert r.returncode == 3 and "is `fap sim --control" in r.stderr     # nobody answers there
    bad = tmp_path / "bad.cap"
    bad.write_text("not a capture\n")
    r = fap("web", "--http", "127.0.0.1:0", "--capture", str(bad))
    assert r.returncode == 3 and r.stderr.startswith("fap: error: ") and "Traceback" not in r.stderr
    r = fap("web", "--http", "127.0.0.1:0", "--capture", str(tmp_path / "missing.cap"))
    assert r.returncode == 3 and "Traceback" not in r.stderr


def test_missing_aiohttp_names_the_extra(tmp_path):
    cap = tmp_path / "b.cap"
    write_capture(cap)
    code = ("import sys; sys.modules['aiohttp'] = None; from fap_py.cli import main; "
            f"sys.exit(main(['web', '--capture', {str(cap)!r}]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip() == "fap: error: fap web needs aiohttp: pip install 'fap_py[web]'"
    code = ("import sys; sys.modules['aiohttp'] = None\nfrom fap_py.web import CaptureSource, WebServer, "
            f"MissingDependencyError\ntry:\n    WebServer(CaptureSource({str(cap)!r}), port=0).start()\n"
            "except MissingDependencyError as e:\n    print('refused', e)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert r.stdout.startswith("refused fap web needs aiohttp"), r.stderr


def test_access_rules(tmp_path):
    from fap_py.web import CaptureSource, WebAccessError, WebServer

    cap = tmp_path / "b.cap"
    write_capture(cap)
    with pytest.raises(WebAccessError, match="needs a token"):
        WebServer(CaptureSource(str(cap)), host="0.0.0.0", port=0)
    with pytest.raises(WebAccessError, match="at least 8"):
        WebServer(CaptureSource(str(cap)), port=0, token="short")
    token = "s3cret-token-123"
    with WebServer(CaptureSource(str(cap)), port=0, token=token) as srv:
        srv.start()
        assert get(srv.url)[0] == 200                            # the page itself: no secret in it
        assert get(srv.url + "api/info")[0] == 401
        assert get(srv.url + "api/info?token=wrong-token-000")[0] == 401
        assert get(srv.url + f"api/info?token={token}")[0] == 200
        assert get(srv.url + "api/stats", {"Authorization": f"Bearer {token}"})[0] == 200
        # control needs the token on loopback too
        from web_helpers import send

        status, ans = send(srv.url + "api/faults", "POST", b"{}")
        assert status == 401 and ans["ok"] is False
        status, ans = send(srv.url + f"api/faults?token={token}", "POST", b'{"kind": "off"}')
        assert status == 400 and "no fault controls" in ans["error"]
    with WebServer(CaptureSource(str(cap)), port=0) as srv:
        srv.start()
        # no token: loopback Host names only (a rebinding DNS name is refused)
        assert get(srv.url + "api/info", {"Host": f"evil.example:{srv.port}"})[0] == 403
        assert get(srv.url + "api/info", {"Host": f"localhost:{srv.port}"})[0] == 200
        from web_helpers import send

        status, ans = send(srv.url + "api/faults", "POST", b"kind=off", content_type="text/plain")
        assert status == 415     # a cross-site form cannot send application/json without a preflight


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="Linux")
def test_source_error_is_shown_not_fatal(tmp_path):
    """A capture that goes bad in the middle: the server stays up and says why."""
    from fap_py.web import CaptureSource, WebServer

    cap = tmp_path / "b.cap"
    write_capture(cap)
    with open(cap, "a") as fh:
        fh.write("12x 0 zz\n")
    with WebServer(CaptureSource(str(cap)), port=0) as srv:
        srv.start()
        assert srv.wait_source(WAIT_S)
        snap = get_json(srv.url + "api/stats")
        assert snap["source"]["done"] and "CaptureFormatError" in snap["source"]["error"]
