"""Helpers of the fap monitor tests: the vectors of the four protocols as
streams, and running the ``fap`` entry point. A uniquely named module (not
conftest) so other components' test helpers cannot shadow it."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional

import pytest

ROOT = Path(__file__).resolve().parents[3]
VECTOR_FILES = {
    "fap": ROOT / "tests" / "c" / "fap" / "vectors" / "fap.json",
    "exec": ROOT / "tests" / "vectors" / "exec_async.json",
    "mikroc": ROOT / "tests" / "vectors" / "mikroc_rs485.json",
    "g485": ROOT / "tests" / "vectors" / "g485.json",
}
#: bytes that start no frame of any protocol (no 'c', DLE, 0x96, 0xFF)
GARBAGE = b"\x00\x01\x55"
RUN_TIMEOUT = 60.0


class Vector(NamedTuple):
    name: str
    frame: bytes
    ok: bool
    reason: Optional[str]
    fields: Dict[str, object]   # the fields the vector file states, JSON-style


def vectors(protocol: str) -> List[Vector]:
    """Every valid and invalid vector of a protocol, fields as --json spells them."""
    doc = json.loads(VECTOR_FILES[protocol].read_text(encoding="utf-8"))
    out = []
    for v in doc.get("valid", []):
        fields: Dict[str, object] = {}
        if protocol == "fap":
            fields = {"msg": v["msg"], "dst": v["dst"], "src": v["src"], "data": v["data"]}
        elif protocol == "exec":
            fields = {"node": v["node"], "seq": v["seq"], "data": v["data"]}
        elif protocol == "mikroc":
            fields = {"address": v["address"], "from_master": v["master"], "data": v["data"]}
        out.append(Vector(v["name"], bytes.fromhex(v["frame"]), True, None, fields))
    for v in doc.get("invalid", []):
        out.append(Vector(v["name"], bytes.fromhex(v["frame"]), False, v["reason"], {}))
    return out


def stream(protocol: str) -> bytes:
    """All vectors of a protocol in one stream, garbage before, between and after."""
    return GARBAGE + b"".join(v.frame + GARBAGE for v in vectors(protocol))


def fap_cmd() -> List[str]:
    """The ``fap`` console script of this interpreter (else ``python -m fap_py``)."""
    script = Path(sys.executable).with_name("fap")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-m", "fap_py"]


def run_fap(*args: str, input: Optional[bytes] = None,
            timeout: float = RUN_TIMEOUT) -> subprocess.CompletedProcess:
    return subprocess.run(fap_cmd() + list(args), input=input, capture_output=True,
                          timeout=timeout, stdin=None if input is not None else subprocess.DEVNULL)


def json_records(stdout: bytes) -> List[dict]:
    return [json.loads(line) for line in stdout.decode().splitlines() if line.strip()]


def need_tool(name: str) -> str:
    """Path of an external tool; skip without it unless CI is set (then fail)."""
    path = shutil.which(name)
    if path:
        return path
    if os.environ.get("CI"):
        pytest.fail(f"{name} is required when CI is set")
    pytest.skip(f"{name} not installed")
    raise AssertionError("unreachable")


def check_records(protocol: str, recs: List[dict], data: bytes) -> None:
    """The records of a vector stream: every byte once, vectors in order, fields right."""
    assert "".join(r["frame"] for r in recs) == data.hex(), "records must tile the stream"
    for r in recs:
        assert r["protocol"] == protocol
        assert r["ok"] == (r["error"] is None)
    it = iter(r for r in recs if r["error"] != "garbage")
    for v in vectors(protocol):
        r = next(it)
        if v.ok:
            assert r["ok"], (v.name, r)
            assert r["frame"] == v.frame.hex(), v.name
            for k, want in v.fields.items():
                assert r[k] == want, (v.name, k, r[k], want)
            if protocol == "g485":
                assert v.name.startswith(r["packet"]) or r["packet"] in v.name or \
                    v.name.startswith("broadcast"), (v.name, r["packet"])
        else:
            assert not r["ok"], (v.name, r)
            assert r["error"] == v.reason, (v.name, r["error"], v.reason)
            assert v.frame.hex().startswith(r["frame"]), v.name
    assert next(it, None) is None
