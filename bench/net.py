"""Network-transport rows of ``python -m bench`` (docs/port.md, "Network transports").

* **Through ser2net**: the master (bench_wire client; the G485 master in
  this process) reaches the paced virtual bus through ser2net on loopback,
  raw ``tcp://`` and ``rfc2217://`` (libfap's own client), against the same
  master on the bus's pty directly; G485 also through pyserial's
  ``socket://`` and ``rfc2217://?ign_set_control``. The slave sits on the
  bus directly. ser2net runs as docs/port.md's recipe says:
  ``chardelay: false`` and ``tcp(nodelay)``; missing ser2net skips these rows.
* **Mismatched baud**: the bus paced at 1 Mbaud, master and slave opened
  at 115200 (the local baud means nothing to the link) against both opened
  at 1,000,000: the engines' pacing must follow the link, not the baud.
"""
from __future__ import annotations

import json
import logging
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional

from bench import servers
from bench.stats import pct, summary, turnarounds

ROOT = Path(__file__).resolve().parents[1]
log = logging.getLogger("bench")

#: the C kinds measured through the transports (bench_wire)
C_NET_KINDS = ("fap-poll", "exec", "mikroc")
#: client transports: name -> URL scheme of libfap ("" = the pty itself) or a pyserial URL
#: ser2net's socket without Nagle (docs/port.md's recipe)
NODELAY = True
MODES = ("direct", "tcp", "rfc2217", "pyserial-socket", "pyserial-rfc2217")


def _ser2net(workdir: Path, mode: str, dev: str, baud: int) -> Any:
    return servers.Ser2net(workdir, [(mode, dev, baud)], {"chardelay": "false"}, nodelay=NODELAY)


def have_ser2net() -> bool:
    return servers.SER2NET is not None


def _client_path(mode: str, s2n: Any, direct: str) -> str:
    if mode == "direct":
        return direct
    port = s2n.ports[0]
    return {"tcp": f"tcp://127.0.0.1:{port}",
            "rfc2217": f"rfc2217://127.0.0.1:{port}?option_ms=50",
            "pyserial-socket": f"socket://127.0.0.1:{port}",
            "pyserial-rfc2217": f"rfc2217://127.0.0.1:{port}?ign_set_control"}[mode]


def net_run(runner: Any, kind: str, baud: int, mode: str, seconds: float) -> Dict[str, Any]:
    """One run: the client through `mode`, the server on the bus directly."""
    from fap_py.vbus import VirtualBus

    tmp = Path(tempfile.mkdtemp(dir=runner.tmp))
    cap = tmp / "bus.cap"
    with VirtualBus(ports=2, baud=baud, seed=1, capture=str(cap)) as bus:
        s2n = None
        if mode != "direct":
            raw = mode in ("tcp", "pyserial-socket")
            s2n = _ser2net(tmp, "raw" if raw else "rfc2217", bus.paths[0], baud)
        try:
            path = _client_path(mode, s2n, bus.paths[0])
            if kind == "g485":
                res = _g485_run(path, bus.paths[1], baud, seconds, mode.startswith("pyserial"))
            else:
                res = _c_run(runner.exe, kind, path, bus.paths[1], baud, seconds)
        finally:
            if s2n is not None:
                s2n.stop()
    res["turnaround_us"] = turnarounds(cap, baud)
    return res


def _c_run(exe: Path, kind: str, client: str, server: str, baud: int, seconds: float,
           client_baud: Optional[int] = None) -> Dict[str, Any]:
    pace = ["--baud", str(client_baud or baud)]
    srv = subprocess.Popen([str(exe), "serve", kind, server] + pace, stdout=subprocess.PIPE, text=True)
    try:
        if srv.stdout is None or srv.stdout.readline().strip() != "ready":
            raise RuntimeError(f"bench_wire serve {kind} did not start")
        cli = subprocess.run([str(exe), "client", kind, client, "--seconds", str(seconds)] + pace,
                             capture_output=True, text=True, timeout=seconds + 60)
        lines = cli.stdout.splitlines()
        if cli.returncode or not lines or not lines[-1].startswith("{"):
            raise RuntimeError(f"bench_wire client {kind} {client}: {cli.stderr.strip()[-300:]}")
        res = json.loads(lines[-1])
    finally:
        srv.terminate()
        srv.wait(10)
    return {"rate": res["exchanges"] / res["seconds"], "failed": res["failed"]}


def _g485_run(client: str, server: str, baud: int, seconds: float,
              pyserial: bool) -> Dict[str, Any]:
    sys.path.insert(0, str(ROOT / "bench" / "g485"))
    import bench_g485 as g

    port: Any = client
    if pyserial:   # an open pyserial object: rfc2217:// as a string is libfap's own client
        import serial

        port = serial.serial_for_url(client, baudrate=baud, timeout=0.05)

    res = g.run_pair([sys.executable, "-m", "fap_py", "g485", "sim", "--address", "1",
                      "--baud", str(baud), "--port", server],
                     lambda: g.g485_client(port, baud, "none"), seconds)
    return {"rate": res["rate"], "failed": res["errors"]}


def _series(runs: List[Dict[str, Any]]) -> Dict[str, Any]:
    if not runs:
        return {"error": "all runs failed"}
    out: Dict[str, Any] = {"rate": summary([r["rate"] for r in runs]),
                           "failed": sum(r["failed"] for r in runs)}
    ta = [t for r in runs for t in r.get("turnaround_us", [])]
    if ta:
        out["turnaround_us"] = {"p50": pct(ta, .5), "p99": pct(ta, .99)}
    return out


def network_series(runner: Any, baud: int, rounds: int, seconds: float,
                   quick: bool = False) -> Dict[str, Any]:
    """{kind: {mode: series}} through ser2net at `baud` (paced); quick (a
    smoke test): FAP direct and through libfap's two transports, G485 through
    libfap's rfc2217:// only (each G485 run starts a Python simulator)."""
    res: Dict[str, Any] = {}
    for kind in ("fap-poll", "g485") if quick else C_NET_KINDS + ("g485",):
        modes = MODES if kind == "g485" and not quick else MODES[:3]
        if quick and kind == "g485":
            modes = ("rfc2217",)
        res[kind] = {}
        for mode in modes:
            runs = []
            for _ in range(rounds):
                try:
                    runs.append(net_run(runner, kind, baud, mode, seconds))
                except Exception as e:   # one failed run is reported, the rest goes on
                    log.warning("%s through %s: run failed: %s", kind, mode, e)
            res[kind][mode] = _series(runs)
    return res


def mismatch_series(runner: Any, rounds: int, seconds: float,
                    quick: bool = False) -> Dict[str, Any]:
    """{kind: {"115200": series, "1000000": series}}: nodes opened at that
    baud on a bus paced at 1 Mbaud (quick: FAP only)."""
    from fap_py.vbus import VirtualBus

    res: Dict[str, Any] = {}
    for kind in ("fap-poll",) if quick else C_NET_KINDS:
        res[kind] = {}
        for node_baud in (115200, 1000000):
            runs = []
            for _ in range(rounds):
                cap = Path(tempfile.mkdtemp(dir=runner.tmp)) / "bus.cap"
                try:
                    with VirtualBus(ports=2, baud=1000000, seed=1, capture=str(cap)) as bus:
                        r = _c_run(runner.exe, kind, bus.paths[0], bus.paths[1], 1000000, seconds,
                                   client_baud=node_baud)
                    r["turnaround_us"] = turnarounds(cap, 1000000)
                    runs.append(r)
                except Exception as e:
                    log.warning("%s mismatched at %d: run failed: %s", kind, node_baud, e)
            res[kind][str(node_baud)] = _series(runs)
    return res


def _cell(s: Dict[str, Any], ref: Optional[Dict[str, Any]] = None) -> str:
    if "error" in s:
        return "failed | | "
    m = s["rate"]["median"]
    share = f" ({100 * m / ref['rate']['median']:.0f} %)" if ref and "rate" in ref else ""
    ta = s.get("turnaround_us")
    tas = f"{ta['p50']:.0f} / {ta['p99']:.0f}" if ta else ""
    return f"{m:.0f} ({s['rate']['min']:.0f}–{s['rate']['max']:.0f}){share} | {tas} | {s['failed']}"


def markdown_lines(res: Dict[str, Any]) -> List[str]:
    L: List[str] = []
    net = res.get("network")
    if net:
        L += ["", f"## Through ser2net on loopback, paced at {net['baud']} baud", "",
              "The master through the transport, the slave on the bus; ser2net `chardelay: false`, "
              "`tcp(nodelay)`. "
              "Share: of the same master on the pty directly. Turnaround: the slave's, from the capture.",
              "", "| protocol | client transport | exchanges/s (share) | turnaround p50 / p99 µs | failed |",
              "|---|---|---|---|---|"]
        for kind, modes in net["rows"].items():
            for mode, s in modes.items():
                L.append(f"| {kind} | {mode} | {_cell(s, modes.get('direct'))} |")
    mm = res.get("mismatch")
    if mm:
        L += ["", "## Mismatched baud: bus paced at 1 Mbaud, nodes opened at 115200", "",
              "| protocol | nodes opened at | exchanges/s (share of matched) | turnaround p50 / p99 µs | failed |",
              "|---|---|---|---|---|"]
        for kind, by in mm.items():
            for nb in ("1000000", "115200"):
                L.append(f"| {kind} | {nb} | {_cell(by[nb], by.get('1000000'))} |")
    return L
