"""``fap web`` against one headless browser (Chromium through selenium): how many frames a
second it sustains to the page, that no frame is lost silently, how late the node table is,
and the server's CPU per frame against ``fap monitor --json`` over the same traffic.

Three runs:

1. throughput: a capture of ``--frames`` exec async frames (request/reply pairs), served by
   ``fap web --capture`` as a process; the page loads it over the stream (a capture keeps
   every frame): frames / (page open -> the page has them all). The server's CPU (child
   rusage, interpreter start included) per frame against ``fap monitor --capture FILE
   --json`` (same start-up) over the same file.
2. live: a paced source in this process publishes ``--rate`` frames/s for ``--seconds`` s
   while the page is open; published == delivered + counted drops for that page (0 silent
   drops), and the page's own ``dropped`` counter.
3. node table latency: during (2), a marker node's request count is bumped every 200 ms;
   the page records (MutationObserver) when its cell shows each value: latency = that
   wall time - the publish time (same machine, same clock). The table is pushed every
   ``fap_py.web._server.STATS_EVERY_S`` (0.1 s): that is the floor.

    python bench/web/bench_web.py [--frames N] [--rate R] [--seconds S] [--json]

Needs chromium, chromedriver and selenium (pip install selenium). Run on an idle machine.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, Dict, List

from fap_py.execasync import encode
from fap_py.web import Source, WebServer


def write_capture(path: str, frames: int) -> None:
    lines = ["# fap-vbus-capture 1 ports=2 baud=1000000"]
    t = 0
    for i in range(frames // 2):
        node = 1 + i % 8
        for port, data in ((0, b"\x01\x02"), (1, bytes(range(12)))):
            lines.append(f"{t} {port} " + encode(node, data, 1 + i % 255).hex(" "))
            t += 150
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def browser() -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--window-size=1400,1000"):
        opts.add_argument(a)
    opts.binary_location = shutil.which("chromium") or "chromium"
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=opts, service=Service(shutil.which("chromedriver") or "chromedriver"))


def child_cpu(argv: List[str], until_ready: bool = False, stop_when=None) -> float:
    """CPU seconds (user + system) of a child process run to its end."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.Popen(argv, stdout=subprocess.PIPE if until_ready else subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    if until_ready:
        ready = json.loads(p.stdout.readline())
        stop_when(ready["url"])
        p.send_signal(signal.SIGTERM)
        p.stdout.read()
    p.wait()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_throughput(frames: int, d: Any) -> Dict[str, Any]:
    tmp = tempfile.mkdtemp(prefix="bench-web-")
    cap = os.path.join(tmp, "b.cap")
    write_capture(cap, frames)
    out: Dict[str, Any] = {}

    def load(url: str) -> None:
        t0 = time.monotonic()
        d.get(url)
        deadline = t0 + 300
        while time.monotonic() < deadline:
            text = d.execute_script("return document.getElementById('shown').textContent")
            if text.startswith(f"{frames} of {frames} frames"):
                break
            time.sleep(0.05)
        else:
            raise SystemExit(f"the page did not get all {frames} frames: {text!r}")
        out["load_s"] = time.monotonic() - t0
        out["page_dropped"] = d.execute_script("return document.getElementById('dropped').textContent")
        out["severe"] = [e for e in d.get_log("browser") if e["level"] == "SEVERE"]
        d.get("about:blank")

    fap = [sys.executable, "-m", "fap_py"]
    out["web_cpu_s"] = child_cpu(fap + ["web", "--http", "127.0.0.1:0", "--capture", cap, "--protocol", "exec",
                                        "--json"], until_ready=True, stop_when=load)
    out["monitor_cpu_s"] = child_cpu(fap + ["monitor", "--capture", cap, "--protocol", "exec", "--json"])
    out["frames"] = frames
    out["fps_to_browser"] = frames / out["load_s"]
    out["web_us_per_frame"] = out["web_cpu_s"] / frames * 1e6
    out["monitor_us_per_frame"] = out["monitor_cpu_s"] / frames * 1e6
    shutil.rmtree(tmp)
    return out


class Paced(Source):
    """``rate`` exec frames a second (request/reply pairs of nodes 1..8) and a marker node 200
    whose request count is bumped on request (the latency probe)."""

    kind = "bench"

    def __init__(self, rate: int, seconds: float) -> None:
        super().__init__("exec", 1_000_000)
        self.rate, self.seconds = rate, seconds
        self.published = 0
        self.marks: List[float] = []
        self.mark = threading.Event()

    def run(self, hub: Any, stop: threading.Event) -> None:
        mon = self._monitor(1_000_000)
        t0 = time.monotonic()
        seq = 0
        tick = 0.01
        n = 0
        while not stop.is_set() and time.monotonic() - t0 < self.seconds:
            want = int((time.monotonic() - t0) * self.rate)
            wire = b""
            while n < want:
                node = 1 + (n // 2) % 8
                wire += encode(node, b"\x01\x02" if n % 2 == 0 else bytes(range(12)), 1 + (n // 2) % 255)
                n += 1
            if self.mark.is_set():
                self.mark.clear()
                seq = seq % 255 + 1
                wire += encode(200, b"\x09", seq)
                self.marks.append(time.time())
            if wire:
                recs = mon.feed(wire, time.monotonic() - t0, 1e-5)
                self.published += len(recs)
                hub.publish(recs)
            stop.wait(tick)


OBSERVE = """
window.__marks = [];
const target = document.querySelector('#nodes tbody');
new MutationObserver(() => {
  const c = document.querySelector('#nodes tr[data-node="200"] td.requests');
  if (!c) return;
  const v = +c.textContent, now = Date.now();
  while (window.__marks.length < v) window.__marks.push([window.__marks.length + 1, now]);  // each value shown
}).observe(target, {childList: true, subtree: true, characterData: true});
"""


def run_live(rate: int, seconds: float, d: Any) -> Dict[str, Any]:
    src = Paced(rate, seconds)
    with WebServer(src, port=0) as srv:
        srv.start()
        d.get(srv.url)
        time.sleep(0.5)      # the page open and connected (a bench, not a test)
        d.execute_script(OBSERVE)
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end - 0.7:
            src.mark.set()
            time.sleep(0.2)
        srv.wait_source(seconds + 10)
        time.sleep(1.0)      # the last table push
        clients = list(srv.hub.clients)
        delivered = [c.cursor - 1 for c in clients]     # the cursor is past the last delivered seq
        dropped = [c.dropped for c in clients]
        marks = d.execute_script("return window.__marks")
        page_dropped = d.execute_script("return document.getElementById('dropped').textContent")
        severe = [e for e in d.get_log("browser") if e["level"] == "SEVERE"]
        d.get("about:blank")
    lat = sorted(t_ms / 1000.0 - src.marks[v - 1] for v, t_ms in marks if v - 1 < len(src.marks))
    published = srv.hub.table.frames
    return {"rate": rate, "seconds": seconds, "published": published,
            "delivered": delivered[0] if delivered else None, "dropped": dropped[0] if dropped else None,
            "silent": (published - delivered[0] - dropped[0]) if delivered else None,
            "page_dropped": page_dropped, "severe": severe, "marks": len(src.marks), "seen": len(lat),
            "table_p50_ms": round(statistics.median(lat) * 1e3, 1) if lat else None,
            "table_p99_ms": round(lat[min(len(lat) - 1, int(0.99 * len(lat)))] * 1e3, 1) if lat else None,
            "table_max_ms": round(lat[-1] * 1e3, 1) if lat else None}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=100000)
    ap.add_argument("--rate", type=int, default=5000)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    d = browser()
    try:
        res = {"load_avg": os.getloadavg(), "throughput": run_throughput(args.frames, d),
               "live": run_live(args.rate, args.seconds, d)}
    finally:
        d.quit()
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    t, lv = res["throughput"], res["live"]
    print(f"load average {res['load_avg'][0]:.2f}")
    print(f"capture of {t['frames']} frames to one browser: {t['load_s']:.2f} s, "
          f"{t['fps_to_browser']:.0f} frames/s; page says {t['page_dropped']}; console errors {len(t['severe'])}")
    print(f"server CPU {t['web_us_per_frame']:.1f} us/frame (fap web, whole process) vs "
          f"{t['monitor_us_per_frame']:.1f} us/frame (fap monitor --json)")
    print(f"live {lv['rate']} frames/s for {lv['seconds']} s: published {lv['published']}, delivered "
          f"{lv['delivered']}, dropped (counted) {lv['dropped']}, silent {lv['silent']}; page says "
          f"{lv['page_dropped']}; console errors {len(lv['severe'])}")
    print(f"node table latency ({lv['seen']} of {lv['marks']} marks seen): p50 {lv['table_p50_ms']} ms, "
          f"p99 {lv['table_p99_ms']} ms, max {lv['table_max_ms']} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
