"""``fap monitor`` on hostile streams and files: linear and bounded in memory
for every protocol (records of bounded size handed on as they come, checked
structurally, never by timing), stopped by SIGTERM/SIGINT on every input
with the summary, bad capture files refused with one line naming the file
(exit 3)."""
from __future__ import annotations

import os
import random
import select
import signal
import subprocess
import time
import tracemalloc
from pathlib import Path
from typing import List

import pytest
from monitor_helpers import fap_cmd, json_records, run_fap, stream
from test_monitor_inputs import write_capture

from fap_py.monitor import Monitor
from fap_py.monitor.decoders import GARBAGE_MAX, HOLD_MAX
from fap_py.vbus import VirtualBus

PROTOCOLS = ["fap", "exec", "mikroc", "g485", "auto"]
WAIT_S = 20.0            # deadline for a record to appear or the monitor to end
#: streams without frame boundaries: noise, a dead line, and runs of each
#: protocol's frame-start byte (the worst case of each codec)
HOSTILE = {
    "random": lambda n: random.Random(1).randbytes(n),
    "zeros": lambda n: bytes(n),
    "ff": lambda n: b"\xff" * n,
    "fap-marker": lambda n: b"c" * n,
    "dle-stx": lambda n: b"\x10\x02" * (n // 2),
    "mikroc-start": lambda n: b"\x96" * n,
}
#: the longest frame of the four protocols (FAP: 1037 bytes + marker)
FRAME_MAX = 1100


def records(protocol: str, data: bytes, step: int = 4096) -> List:
    mon = Monitor(protocol)
    out = []
    for i in range(0, len(data), step):
        out += mon.feed(data[i:i + step])
    return out + mon.finish()


@pytest.mark.parametrize("kind", sorted(HOSTILE))
@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_unframed_stream_gives_bounded_records_tiling_the_input(protocol, kind):
    data = HOSTILE[kind](64 * 1024)
    recs = records(protocol, data)
    assert b"".join(r.raw for r in recs) == data, "records must tile the stream once"
    for r in recs:
        limit = GARBAGE_MAX if r.error == "garbage" else FRAME_MAX
        assert len(r.raw) <= limit, (r.error, len(r.raw))


@pytest.mark.parametrize("kind", ["random", "zeros"])
@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_memory_does_not_grow_with_the_input(protocol, kind):
    """Peak Python memory while decoding 256 kB is what 32 kB needs (records dropped):
    holding the input would add 224 kB."""
    def peak(n: int) -> int:
        data = HOSTILE[kind](n)
        mon = Monitor(protocol)
        tracemalloc.start()
        try:
            for i in range(0, n, 8192):
                mon.feed(data[i:i + 8192])
            mon.finish()
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    small, large = peak(32 * 1024), peak(256 * 1024)
    assert large < small + 2 * HOLD_MAX + 48 * 1024, (small, large)


def read_line(proc: subprocess.Popen) -> bytes:
    ready, _, _ = select.select([proc.stdout], [], [], WAIT_S)
    assert ready, "no output from the monitor"
    line = proc.stdout.readline()
    assert line, f"monitor ended: rc={proc.wait()} {proc.stderr.read()!r}"
    return line


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_records_come_before_the_end_of_a_pipe(protocol):
    """`cat /dev/zero | fap monitor`: garbage records appear while the pipe is open."""
    proc = subprocess.Popen(fap_cmd() + ["monitor", "--protocol", protocol, "--json"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        proc.stdin.write(bytes(64 * 1024))
        proc.stdin.flush()
        (rec,) = json_records(read_line(proc))
        assert rec["error"] == "garbage" and len(rec["frame"]) // 2 <= GARBAGE_MAX
        assert proc.poll() is None, "the pipe is still open"
    finally:
        proc.kill()
        proc.wait()


def start(args: List[str], stdin=subprocess.DEVNULL) -> subprocess.Popen:
    return subprocess.Popen(fap_cmd() + ["monitor"] + args, stdin=stdin,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def wait_end(proc: subprocess.Popen) -> bytes:
    try:
        out, _err = proc.communicate(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        pytest.fail("the monitor did not end on the signal")
    return out


def wait_stderr(proc: subprocess.Popen, text: bytes) -> None:
    seen = b""
    deadline = time.monotonic() + WAIT_S
    while text not in seen:
        ready, _, _ = select.select([proc.stderr], [], [], max(0.0, deadline - time.monotonic()))
        assert ready, f"monitor did not say {text!r}: {seen!r}"
        chunk = os.read(proc.stderr.fileno(), 4096)
        assert chunk, f"monitor ended: {seen!r}"
        seen += chunk


@pytest.mark.parametrize("sig,rc", [(signal.SIGTERM, 0), (signal.SIGINT, 130)])
def test_signal_ends_a_pipe_that_never_ends_with_the_summary(sig, rc):
    """`sleep 100 | fap monitor --protocol exec` then SIGTERM/SIGINT: ends, footer printed."""
    r, w = os.pipe()
    try:
        proc = start(["--protocol", "exec"], stdin=r)
        os.write(w, bytes(1000))              # > GARBAGE_MAX: a record shows it is reading
        read_line(proc)
        proc.send_signal(sig)
        out = wait_end(proc)
    finally:
        os.close(r)
        os.close(w)
    assert proc.returncode == rc
    assert b"-- 0 frames, errors: garbage" in out and b"1000 bytes" in out


@pytest.mark.parametrize("sig,rc", [(signal.SIGTERM, 0), (signal.SIGINT, 130)])
def test_signal_ends_a_raw_fifo_and_an_endless_raw_device(sig, rc, tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    proc = start(["--protocol", "fap", "--raw", str(fifo)])
    w = os.open(fifo, os.O_WRONLY)           # the monitor's open returns: it reads now
    try:
        os.write(w, bytes(1000))
        read_line(proc)
        proc.send_signal(sig)
        out = wait_end(proc)
    finally:
        os.close(w)
    assert proc.returncode == rc and b"1000 bytes" in out
    endless = start(["--protocol", "g485", "--raw", "/dev/zero"])
    read_line(endless)
    endless.send_signal(sig)
    out = wait_end(endless)
    assert endless.returncode == rc and b"-- 0 frames, errors: garbage" in out


def test_sigterm_ends_a_long_capture_with_the_summary(tmp_path):
    cap = tmp_path / "big.cap"
    data = random.Random(2).randbytes(3_000_000)
    write_capture(cap, data)
    proc = start(["--protocol", "mikroc", "--capture", str(cap)])
    read_line(proc)
    proc.send_signal(signal.SIGTERM)
    out = wait_end(proc)
    assert proc.returncode == 0
    footer = [ln for ln in out.decode().splitlines() if ln.startswith("-- ")]
    assert len(footer) == 1
    read = int(footer[0].split(";")[1].split()[0])
    assert 0 < read < len(data), "stopped in the middle"


def test_sigterm_ends_a_live_port_with_the_summary():
    with VirtualBus(ports=2) as bus:
        proc = start(["--protocol", "exec", "--port", bus.paths[1], "--follow"])
        wait_stderr(proc, b"listening on")
        proc.send_signal(signal.SIGTERM)
        out = wait_end(proc)
    assert proc.returncode == 0 and b"-- 0 frames" in out


@pytest.mark.parametrize("content,why", [
    ("1000 0 00 01\n-5 0 00\n", "bad data line"),
    (f"1000 0 00 01\n{2**32 * 10**6} 0 00\n", "beyond 2**32 s"),
    ("# fap-vbus-capture 1 ports=2 baud=-1 echo=0 seed=0\n1000 0 00\n", "baud=-1"),
    ("# fap-vbus-capture 1 ports=2 baud=x echo=0 seed=0\n1000 0 00\n", "baud=x"),
    ("1000 300 00\n", "sender beyond 255"),
    ("1000 0 " + "00 " * 30000 + "\n", "longer than"),
])
@pytest.mark.parametrize("pcap", [False, True])
def test_bad_capture_one_line_naming_the_file_exit_3(content, why, pcap, tmp_path):
    cap = tmp_path / "bad.cap"
    cap.write_text(content)
    extra = ["--pcap", str(tmp_path / "o.pcap")] if pcap else []
    res = run_fap("monitor", "--capture", str(cap), "--protocol", "fap", *extra)
    err = res.stderr.decode()
    assert res.returncode == 3, err
    assert err.count("\n") == 1 and err.startswith(f"fap: error: {cap}: ") and why in err, err


@pytest.mark.parametrize("path,why", [
    ("/etc/passwd", "/etc/passwd: line 1: bad data line"),
    ("/dev/zero", "/dev/zero: capture file: not a regular file"),
    ("/", "/: capture file: a directory"),
])
def test_system_files_as_capture(path, why):
    res = run_fap("monitor", "--capture", path, timeout=WAIT_S)
    err = res.stderr.decode()
    assert res.returncode == 3 and err.count("\n") == 1 and why in err, err


def test_capture_of_a_pipeline_is_refused(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    proc = start(["--capture", str(fifo)])
    w = os.open(fifo, os.O_WRONLY)
    try:
        out = wait_end(proc)
    finally:
        os.close(w)
    assert proc.returncode == 3 and not out


def test_vector_streams_unchanged_by_the_bounds():
    """A frame stream decodes the same in one piece and byte by byte."""
    for protocol in ("fap", "exec", "mikroc", "g485"):
        data = stream(protocol)
        whole = [(r.error, r.raw) for r in records(protocol, data, len(data))]
        single = [(r.error, r.raw) for r in records(protocol, data, 1)]
        assert [e for e in whole if e[0] != "garbage"] == \
            [e for e in single if e[0] != "garbage"], protocol


def test_read_capture_refuses_devices_and_huge_files(tmp_path):
    """vbus.read_capture (which holds the file) checks type and size first."""
    from fap_py.errors import FileError
    from fap_py.vbus import MAX_CAPTURE_BYTES, read_capture

    with pytest.raises(FileError, match="/dev/zero: capture file: not a regular file"):
        read_capture("/dev/zero")
    huge = tmp_path / "huge.cap"
    with open(huge, "wb") as fh:               # sparse: no disk used
        fh.truncate(MAX_CAPTURE_BYTES + 1)
    with pytest.raises(FileError, match="more than"):
        read_capture(huge)


@pytest.mark.parametrize("sig,rc", [(signal.SIGTERM, 0), (signal.SIGINT, 130)])
def test_signal_ends_a_monitor_whose_reader_stopped_reading(sig, rc):
    """stdout is a pipe nobody reads: the write blocks; the signal still ends the
    monitor, and the summary goes to stderr."""
    import fcntl
    import termios

    proc = start(["--protocol", "g485", "--raw", "/dev/zero"])
    fd = proc.stdout.fileno()
    size = fcntl.fcntl(fd, 1032)                   # F_GETPIPE_SZ
    deadline = time.monotonic() + WAIT_S
    while True:               # wait until the pipe is full and the monitor waits in a write
        buf = bytearray(4)
        fcntl.ioctl(fd, termios.FIONREAD, buf)
        try:
            wchan = Path(f"/proc/{proc.pid}/wchan").read_text()
        except OSError:
            wchan = "0"
        blocked = "pipe" in wchan or wchan == "0"       # "0": the kernel does not say
        if int.from_bytes(buf, "little") >= size // 2 and blocked:
            break
        assert time.monotonic() < deadline, "the monitor never filled its stdout"
        select.select([], [], [], 0.01)
    proc.send_signal(sig)
    try:
        proc.wait(timeout=WAIT_S)           # stdout stays unread: the write stays blocked
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        pytest.fail("the monitor blocked in a write did not end on the signal")
    err = proc.stderr.read()
    proc.stdout.close()
    assert proc.returncode == rc
    assert b"-- 0 frames, errors: garbage" in err

