"""A hostile call over every public callable of ``fap_py.monitor`` (every
module's ``__all__``, subpackage modules found by walking the package, so a
new module cannot escape): each bad value must raise an exception of the
package's hierarchy (``fap_py.errors.FapError``), never a generic one,
never be accepted silently, never hang. Bytes-like inputs are accepted."""
from __future__ import annotations

import importlib
import inspect
import io
import math
import pkgutil
import signal
from array import array
from typing import Any, Callable, Dict, List, Tuple

import pytest

import fap_py.monitor as monitor_pkg
from fap_py.errors import FapError, InvalidTypeError, InvalidValueError
from fap_py.monitor import Event, Monitor, Record
from fap_py.monitor.session import SessionConfig
from fap_py.monitor.stats import Stats
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus

CALL_LIMIT_S = 10        # a call that takes longer hangs
BAD: List[Any] = [None, -1, 2**64, float("nan"), float("inf"), -0.5, "x", "", b"\xff",
                  object(), True, [1]]


def _bytes_like(v: Any) -> bool:
    return isinstance(v, (bytes, bytearray, memoryview))


def _path_like(v: Any) -> bool:
    return isinstance(v, (str, bytes)) and v not in ("", b"")


#: parameter name -> the bad values that are in fact valid for it
ACCEPTS: Dict[str, Callable[[Any], bool]] = {
    "data": _bytes_like, "raw": _bytes_like,
    "t": lambda v: v is None, "t_end": lambda v: v is None, "t0": lambda v: v is None,
    "port": lambda v: v is None, "fields": lambda v: v is None, "epoch": lambda v: v is None,
    "idle_s": lambda v: v is None, "rs485": lambda v: v is None,
    "error": lambda v: v is None or isinstance(v, str),
    "final": lambda v: v is True, "flush": lambda v: v is True,
    "argv": lambda v: v is None,
    "directory": _path_like, "path": _path_like,
    "asked": lambda v: True,     # a plug-in's pairing key: any value, only compared
    # monitor.session: an input or output file is any path or None; the switches are bools
    "device": lambda v: v is None or _path_like(v), "raw_file": lambda v: v is None or _path_like(v),
    "capture_file": lambda v: v is None or _path_like(v),
    "pcap_file": lambda v: v is None or _path_like(v),
    "as_json": lambda v: v is True, "stats_only": lambda v: v is True, "quiet": lambda v: v is True,
    "out": lambda v: v is None, "utilisation": lambda v: v is None,
}


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def call(fn: Callable, *args: Any, **kw: Any) -> Tuple[str, Any]:
    """('ok', result) | ('fap', exc) | ('generic', exc) | ('hang', None)."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CALL_LIMIT_S)
    try:
        return "ok", fn(*args, **kw)
    except Hang:
        return "hang", None
    except FapError as exc:
        return "fap", exc
    except Exception as exc:                       # a generic one: what the test looks for
        return "generic", exc
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def public_modules() -> List[Any]:
    mods = [monitor_pkg]
    for info in pkgutil.walk_packages(monitor_pkg.__path__, monitor_pkg.__name__ + "."):
        mods.append(importlib.import_module(info.name))
    return mods


@pytest.fixture
def good(tmp_path, monkeypatch) -> Dict[str, Any]:
    """A valid value for every parameter name of the public API."""
    monkeypatch.chdir(tmp_path)
    cap = tmp_path / "bus.cap"
    cap.write_text("# fap-vbus-capture 1 ports=2 baud=9600 echo=0 seed=0\n1000 0 00 01\n")
    ev = Event("g485", 0, b"\xff\xff\x03\x02\x7f\x7b", None)
    r, w = __import__("os").pipe()
    bus = VirtualBus(ports=2)
    values = {
        "protocol": "fap", "baud": 9600, "data": b"\x00\x01", "t": 1.0, "char_s": 0.001,
        "port": 1, "now_ns": 1, "event": ev, "rec": Record(ev, 1.0, 1.1, 0), "events": [ev],
        "t_end": 1.1, "offset": 0, "raw": b"\x00", "error": None, "fields": None,
        "final": False, "flush": False, "gap_ns": 0, "directory": str(tmp_path / "d"),
        "argv": ["--extcap-interfaces"], "fh": io.BytesIO(), "epoch": None, "t0": None,
        "stop": lambda: True, "deadline": lambda: None, "idle_s": 0.0, "rs485": None,
        "fd": r, "path": str(cap), "asked": None,
        "device": None, "raw_file": None, "capture_file": str(cap), "as_json": False,
        "stats_only": False, "pcap_file": None, "quiet": True, "out": io.StringIO(),
        "frames": 1, "errors": {"crc": 1}, "bytes": 4, "frame_bytes": 4, "utilisation": 0.5, "nodes": {"1": {"frames": 1}},
    }
    values["config"] = SessionConfig(capture_file=str(cap), quiet=True)
    values["_live_path"] = bus.paths[1]
    yield values
    bus.close()
    for fd in (r, w):
        __import__("os").close(fd)


def targets(good: Dict[str, Any]) -> List[Tuple[str, Callable]]:
    """Every public function, class and public method of an instance."""
    out: List[Tuple[str, Callable]] = []
    for mod in public_modules():
        names = getattr(mod, "__all__", None)
        assert names is not None, f"{mod.__name__} must declare __all__ (its public API)"
        for name in names:
            obj = getattr(mod, name)
            if not callable(obj):
                continue
            label = f"{mod.__name__}.{name}"
            out.append((label, obj))
            if inspect.isclass(obj):
                inst = instance(obj, good)
                for mname, _m in inspect.getmembers(obj, callable):
                    if not mname.startswith("_"):
                        out.append((f"{label}().{mname}", getattr(inst, mname)))
    return out


def instance(cls: type, good: Dict[str, Any]) -> Any:
    if cls.__name__ == "LivePort":
        return cls(good["_live_path"], 9600, RS485(mode=RS485Mode.NONE))
    return cls(*good_args(cls, good))


def params(fn: Callable) -> List[inspect.Parameter]:
    return [p for p in inspect.signature(fn).parameters.values()
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.POSITIONAL_ONLY)]


def good_args(fn: Callable, good: Dict[str, Any]) -> List[Any]:
    out = []
    for p in params(fn):
        if p.name == "path" and "LivePort" in getattr(fn, "__qualname__", ""):
            out.append(good["_live_path"])
        else:
            out.append(good[p.name])
    return out


def test_every_public_callable_refuses_bad_values(good):
    findings = []
    seen = 0
    for label, fn in targets(good):
        ps = params(fn)
        base = good_args(fn, good)
        if not ps:
            kind, res = call(fn)
            if kind in ("generic", "hang"):
                findings.append(f"{label}(): {kind} {res!r}")
            seen += 1
            continue
        for i, p in enumerate(ps):
            for bad in BAD:
                if p.name in ACCEPTS and ACCEPTS[p.name](bad):
                    continue
                args = list(base)
                args[i] = bad
                kind, res = call(fn, *args)
                seen += 1
                if kind != "fap":
                    findings.append(f"{label}({p.name}={bad!r}): {kind} {res!r}")
    assert seen > 300, seen
    assert not findings, "\n".join(findings)


@pytest.mark.parametrize("data", [
    b"\x10\x02\x07\x00\x41\x42\x10\x03\xa1\x05",
    bytearray(b"\x10\x02\x07\x00\x41\x42\x10\x03\xa1\x05"),
    memoryview(b"\x10\x02\x07\x00\x41\x42\x10\x03\xa1\x05"),
    memoryview(b"\x10\x00\x02\x00\x07\x00\x00\x00\x41\x00\x42\x00\x10\x00\x03\x00\xa1\x00\x05\x00")[::2],
    memoryview(array("B", b"\x10\x02\x07\x00\x41\x42\x10\x03\xa1\x05")),
])
def test_bytes_like_inputs_are_accepted(data):
    mon = Monitor("exec")
    recs = mon.feed(data) + mon.finish()
    assert b"".join(r.raw for r in recs) == bytes(data)


@pytest.mark.parametrize("call_,exc", [
    (lambda: Monitor("auto", -1), InvalidValueError),
    (lambda: Monitor("auto", 2**32), InvalidValueError),
    (lambda: Monitor(None), InvalidTypeError),
    (lambda: Monitor("modbus"), InvalidValueError),
    (lambda: Monitor().feed(b"\x00", now_ns=2**64), InvalidValueError),
    (lambda: Monitor().feed(None), InvalidTypeError),
    (lambda: Monitor().feed("text"), InvalidTypeError),
    (lambda: Monitor().feed(b"\x00", char_s=math.nan), InvalidValueError),
    (lambda: Monitor().feed(b"\x00", char_s=math.inf), InvalidValueError),
    (lambda: Monitor().feed(b"\x00", char_s=-1), InvalidValueError),
    (lambda: Monitor().feed(b"\x00", t=-1.0), InvalidValueError),
    (lambda: Monitor().feed(b"\x00", port=256), InvalidValueError),
    (lambda: Monitor().idle(-1), InvalidValueError),
    (lambda: Stats().add(None), InvalidTypeError),
    (lambda: Stats(-1), InvalidValueError),
])
def test_the_issue_calls_raise_specific_errors(call_, exc):
    with pytest.raises(exc):
        call_()
