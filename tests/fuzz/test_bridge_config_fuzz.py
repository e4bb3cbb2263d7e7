"""``fap bridge --config FILE --check`` under hypothesis (issue 26): the shipped
example with random bytes written over it, cut short, or spliced with hostile
TOML, ends with exit 0 (valid), 2 (a config error: one line naming the
field) or 3 (a file it names cannot be used), never "internal error" or a
traceback, and creates nothing (``--check``). Through the entry point, in
process. Runs in seconds (BRIDGE_FUZZ_EXAMPLES scales it); part of
.ci/fuzz.sh."""
from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

import pytest

try:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
except ImportError:                         # CI installs it: a missing tool fails there
    if os.environ.get("CI"):
        raise
    pytest.skip("hypothesis not installed", allow_module_level=True)

from fap_py.cli import main

EXAMPLE = (Path(__file__).resolve().parents[2] / "examples" / "bridge" / "bridge.toml").read_bytes()
EXAMPLES = int(os.environ.get("BRIDGE_FUZZ_EXAMPLES", "200"))
SPLICES = [b"[[bus]]\n", b"bus = [1]\n", b'bus = ["ab"]\n', b"[[bus]]\nname = 5\n", b"x = " + b"[" * 3000,
           b'url = "mqtt://[::1"\n', b'password_file = "/dev/zero"\n', b"\xff\xfe\x00", b"= =\n",
           b"baud = 99999999999999999999999\n", b"slaves = [0, 32, -1]\n", b'rs485 = "gpio"\n',
           b'[metrics]\nlisten = "nowhere"\n', b"qos = 1e999\n", b'protocol = "exec"\n', b"\n[bridge]\n"]


def _check(tmp: Path, text: bytes) -> None:
    cfg = tmp / "bridge.toml"
    cfg.write_bytes(text)
    state = tmp / "state"
    before = sorted(p.name for p in tmp.iterdir())
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        code = main(["bridge", "--config", str(cfg), "--check"])
    assert code in (0, 2, 3), (text[:300], code, err.getvalue())
    msg = err.getvalue()
    assert "internal error" not in msg and "Traceback" not in msg, (text[:300], msg)
    assert msg.count("\n") <= 1 and len(msg) < 2000, msg[:500]
    assert sorted(p.name for p in tmp.iterdir()) == before and not state.exists()   # --check makes nothing


def test_bridge_config_files(tmp_path):
    @settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    @given(cut=st.integers(0, len(EXAMPLE)),
           edits=st.lists(st.tuples(st.integers(0, len(EXAMPLE)),
                                    st.one_of(st.binary(max_size=8), st.sampled_from(SPLICES))), max_size=3))
    def run(cut, edits):
        text = bytearray(EXAMPLE[:cut] if cut % 3 == 0 else EXAMPLE)
        for at, piece in edits:
            at = min(at, len(text))
            text[at:at + len(piece)] = piece
        d = tmp_path / f"t{os.urandom(4).hex()}"
        d.mkdir()
        _check(d, bytes(text))

    run()
