"""``fap g485 sim`` in its own process, driven by ``fap g485 read/write/set/...``."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

sys.path.append(str(Path(__file__).resolve().parents[1] / "serve"))  # last: never shadows a conftest
from serve_helpers import start_daemon  # the daemon tests' own starter


class Result:
    def __init__(self, returncode: int, stdout: str, stderr: str) -> None:
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


@pytest.fixture
def fap(capsys):
    """Run ``fap g485 ARGS`` in this process (the simulator is the separate process)."""
    from fap_py.cli import main

    def run(*args: str) -> Result:
        code = main(["g485", *args])
        out = capsys.readouterr()
        return Result(code, out.out, out.err)

    return run


@pytest.fixture(params=["direct", "daemon"])
def sim_process(request, vbus, tmp_path):
    """The simulator process on port 1; the commands' port: port 0, or a ``fap serve``
    on it (the commands take ``fapd://`` URLs unchanged: same output, exit codes)."""
    proc = subprocess.Popen([sys.executable, "-m", "fap_py", "g485", "sim", "--port", vbus.paths[1],
                             "--address", "1", "--address", "4", "--eeprom-dir", str(tmp_path)],
                            stdout=subprocess.PIPE, text=True, cwd=tmp_path)  # the installed package
    assert "simulating G485 devices 1, 4" in proc.stdout.readline()
    daemon = start_daemon(str(tmp_path), vbus.paths[0], protocol="g485") if request.param == "daemon" else None
    try:
        yield (daemon.url if daemon else vbus.paths[0]), tmp_path
    finally:
        if daemon is not None:
            daemon.stop()
        proc.terminate()
        assert proc.wait(10) == 0
        proc.stdout.close()


def test_cli_transactions_against_simulator_process(sim_process, fap):
    port, eeprom_dir = sim_process
    base = ["--port", port, "--timeout", "0.2"]
    r = fap("read", *base, "--address", "4", "--register", "1", "--registers", "7")
    assert r.returncode == 0, r.stderr
    assert "register 7: 4 (0x04)" in r.stdout
    assert fap("write", *base, "--address", "4", "--register", "8", "0x32", "7").returncode == 0
    assert "register 9: 7" in fap("read", *base, "--address", "4", "--register", "8", "--registers", "2").stdout
    assert fap("set", *base, "--address", "4", "save_eeprom").returncode == 0
    assert (eeprom_dir / "g485-4.json").exists()
    assert fap("error-word", *base, "--address", "1").stdout.startswith("0x0000")
    assert fap("handshake", *base, "--address", "1").stdout.startswith("0x")
    r = fap("read", *base, "--address", "0", "--register", "1")
    assert r.returncode == 2 and "cannot be broadcast" in r.stderr   # usage error
    r = fap("read", *base, "--address", "9", "--register", "1", "--retries", "0")
    assert r.returncode == 1 and "no reply" in r.stderr


def test_example_fan_bus_runs():
    from pathlib import Path

    example = Path(__file__).resolve().parents[3] / "examples" / "g485" / "fan_bus.py"
    r = subprocess.run([sys.executable, str(example)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "fan 30 now runs at 70 %" in r.stdout and "READ_ONLY" in r.stdout
