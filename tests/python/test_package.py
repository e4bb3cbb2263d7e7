"""The installed package: extension built and packaged, CLI reachable."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Dict, List, Set, Tuple

import pytest

import fap_py


def test_imported_from_installed_package_not_source_tree() -> None:
    source_pkg = Path(__file__).resolve().parents[2] / "fap_py"
    assert Path(fap_py.__file__).resolve().parent != source_pkg
    assert "site-packages" in Path(fap_py.__file__).resolve().parts


def test_native_extension_reports_core_version() -> None:
    assert fap_py.native_version() == fap_py.__version__


def test_cli_help_lists_subcommands(tmp_path: Path) -> None:
    # cwd outside the source tree: its fap_py/ (no compiled _native) must not shadow the install
    out = subprocess.run([sys.executable, "-m", "fap_py", "--help"], cwd=tmp_path,
                         check=True, capture_output=True, text=True).stdout
    assert "usage: fap" in out
    assert "version" in out


def test_error_hierarchy_is_rooted_in_faperror() -> None:
    import errno

    err = fap_py.errors.error_from_code(-errno.EIO, "write", "/dev/ttyX")
    assert isinstance(err, fap_py.PortError) and isinstance(err, OSError)
    assert err.errno == errno.EIO and "/dev/ttyX" in str(err)
    assert isinstance(fap_py.errors.error_from_code(-10001), fap_py.BusCollisionError)
    assert issubclass(fap_py.InvalidValueError, ValueError)
    assert issubclass(fap_py.FapTimeoutError, TimeoutError)


# -- one rule in one place: every constant, limit, default and stats struct is C's --

def _c_fields(ctype: str) -> list:
    from fap_py._native import ffi

    return [name for name, _ in ffi.typeof(ctype).fields]


def test_python_constants_equal_the_compiled_core() -> None:
    from fap_py import execasync, fap, mikroc, vbus
    from fap_py._native import lib

    pairs = {
        "fap.MAX_ID": (fap.MAX_ID, lib.FAPX_MAX_ID),
        "fap.MAX_DATA": (fap.MAX_DATA, lib.FAPX_MAX_DATA),
        "exec.DLE": (execasync.DLE, lib.EXEC_ASYNC_DLE),
        "exec.STX": (execasync.STX, lib.EXEC_ASYNC_STX),
        "exec.ETX": (execasync.ETX, lib.EXEC_ASYNC_ETX),
        "exec.BROADCAST": (execasync.BROADCAST, lib.EXEC_ASYNC_BROADCAST),
        "exec.MAX_DATA": (execasync.MAX_DATA, lib.EXEC_ASYNC_MAX_DATA),
        "exec.MAX_FRAME": (execasync.MAX_FRAME, lib.EXEC_ASYNC_MAX_FRAME),
        "mikroc.START_BYTE": (mikroc.START_BYTE, lib.MIKROC_RS485_START_BYTE),
        "mikroc.STOP_BYTE": (mikroc.STOP_BYTE, lib.MIKROC_RS485_STOP_BYTE),
        "mikroc.BROADCAST": (mikroc.BROADCAST, lib.MIKROC_RS485_BROADCAST),
        "mikroc.MAX_DATA": (mikroc.MAX_DATA, lib.MIKROC_RS485_MAX_DATA),
        "mikroc.Master buffer": (mikroc.Master._buffer_size, lib.MIKROC_RS485_MASTER_BUFFER),
        "mikroc.Slave buffer": (mikroc.Slave._buffer_size, lib.MIKROC_RS485_SLAVE_BUFFER),
        "vbus.MAX_PORTS": (vbus.MAX_PORTS, lib.FAP_VBUS_MAX_PORTS),
        "errors.ECOLLISION": (fap_py.errors.FAP_PORT_ECOLLISION, lib.FAP_PORT_ECOLLISION),
        "errors.ECLOSED": (fap_py.errors.FAP_PORT_ECLOSED, lib.FAP_PORT_ECLOSED),
    }
    bad = {k: v for k, v in pairs.items() if v[0] != v[1]}
    assert not bad
    assert fap.Master._mode == lib.FAPX_MASTER and fap.Slave._mode == lib.FAPX_SLAVE
    for kind in fap.EventKind:
        assert kind.value == getattr(lib, f"FAPX_EV_{kind.name}")
    for st in execasync.Status:
        assert st.value == getattr(lib, f"EXEC_ASYNC_{st.name}")
    for sr in execasync.ServeResult:
        if sr.name != "TIMEOUT":
            assert sr.value == getattr(lib, f"EXEC_SLAVE_{sr.name}")
    for mode in fap_py.RS485Mode:
        assert mode.value == getattr(lib, f"FAP_RS485_{mode.name}")
    from fap_py.mikroc.errors import _ERRORS

    for code, cls in _ERRORS.items():
        assert code == getattr(lib, "MIKROC_RS485_" + {
            "ChecksumError": "ECRC", "FormatError": "EFORMAT", "ShortFrameError": "ESHORT",
            "LongFrameError": "ELONG", "AbortedFrameError": "EABORT",
            "OverrunError": "EOVERRUN"}[cls.__name__])


def test_stats_dataclasses_name_every_c_counter() -> None:
    from dataclasses import fields

    from fap_py import execasync, fap, mikroc, port, vbus

    for cls, ctype, skip in ((fap.Stats, "fapx_stats", ()),
                             (execasync.MasterStats, "execMasterStats", ()),
                             (execasync.SlaveStats, "execSlaveStats", ()),
                             (mikroc.NodeStats, "mikrocRS485_stats",
                              ("last_rx_error", "last_send_error", "last_address")),
                             (vbus.VirtualBusStats, "fap_vbus_stats", ()),
                             (port.PortStats, "fap_port_stats", ())):
        want = [n for n in _c_fields(ctype) if n not in skip]
        assert [f.name for f in fields(cls)] == want, cls.__name__


def test_rs485_defaults_are_the_c_port_layers() -> None:
    from fap_py._native import ffi, lib
    from fap_py.rs485 import DEFAULT_BAUD, RS485, RS485Mode, c_defaults

    po = ffi.new("fap_port_options *")
    lib.fap_port_options_init(po)
    assert DEFAULT_BAUD == po.baud
    # Python has no defaults of its own: RS485() leaves C's struct untouched
    mine = ffi.new("fap_port_options *")
    lib.fap_port_options_init(mine)
    RS485().apply_to(mine, po.baud)
    assert bytes(ffi.buffer(mine)) == bytes(ffi.buffer(po))
    d = c_defaults()
    assert d["mode"] == po.rs485_mode
    for name, _ in ffi.typeof("fap_port_options").fields:
        if name not in ("baud", "rs485_mode", "gpio_chip", "rt"):
            assert d[name] == getattr(po, name), name
    assert po.gpio_chip == ffi.NULL and d["gpio_chip"] is None
    assert d["realtime"] == "off" and (po.rt.policy, po.rt.mlock, po.rt.cpus) == (0, 0, 0)
    # and a field that is given is what C gets
    RS485(mode=RS485Mode.NONE, turnaround_us=7, exclusive=False).apply_to(mine, 9600)
    assert (mine.rs485_mode, mine.turnaround_us, mine.exclusive, mine.baud) == (
        lib.FAP_RS485_NONE, 7, 0, 9600)


def test_exec_master_defaults_are_the_c_engines(tmp_path: Path) -> None:
    from fap_py._native import ffi, lib
    from fap_py.execasync import Master
    from fap_py.rs485 import RS485, RS485Mode
    from fap_py.vbus import VirtualBus

    mo = ffi.new("execMasterOptions *")
    lib.execMasterOptionsInit(mo)
    with VirtualBus(ports=2) as bus, Master(bus.paths[0], rs485=RS485(mode=RS485Mode.NONE)) as m:
        assert m._retries == mo.retries


def _import_graph() -> Dict[str, Set[str]]:
    """Every fap_py module (``pkgutil.walk_packages``: subpackages, private and compiled
    modules included) -> the fap_py modules it imports anywhere in its text (at the
    top, inside a function, under TYPE_CHECKING). ``from .x import name`` counts
    ``x.name`` when that is a module, else ``x``."""
    import ast
    import importlib.util
    import pkgutil

    mods = {"fap_py"} | {i.name for i in pkgutil.walk_packages(fap_py.__path__, "fap_py.")}

    def owner(name: str) -> str:
        while name not in mods:
            name = name.rpartition(".")[0]
        return name

    graph: Dict[str, Set[str]] = {}
    for mod in sorted(mods):
        spec = importlib.util.find_spec(mod)
        assert spec is not None and spec.origin, mod
        graph[mod] = deps = set()
        if not spec.origin.endswith(".py"):
            continue                          # the compiled core: imports nothing of fap_py
        package = mod if spec.submodule_search_locations else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(Path(spec.origin).read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                deps |= {owner(a.name) for a in node.names if a.name.split(".")[0] == "fap_py"}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[:len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                if base.split(".")[0] != "fap_py":
                    continue
                deps |= {f"{base}.{a.name}" if f"{base}.{a.name}" in mods else owner(base)
                         for a in node.names}
        deps.discard(mod)
    return graph


def _cycles(graph: Dict[str, Set[str]]) -> List[Tuple[str, ...]]:
    """The strongly connected groups of more than one module (Tarjan), each sorted."""
    index: Dict[str, int] = {}
    low: Dict[str, int] = {}
    stack: List[str] = []
    found: List[Tuple[str, ...]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(tuple(sorted(group)))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


#: Cycles this branch found in files other work owns, each with that work; the test
#: fails when one is gone (delete it here) and when a new one appears. Empty it as
#: those branches land: the goal is no cycle at all.
KNOWN_CYCLES: Dict[Tuple[str, ...], str] = {
}


def test_walk_finds_every_module_and_import() -> None:
    graph = _import_graph()
    for mod in ("fap_py._native", "fap_py.monitor.session", "fap_py.bridge.bridge",
                "fap_py.g485.master", "fap_py.commands.monitor"):
        assert mod in graph, mod
    assert "fap_py._native" in graph["fap_py.errors"]               # a lazy import
    assert "fap_py.monitor.session" in graph["fap_py.monitor.extcap"]
    assert "fap_py.errors" in graph["fap_py.monitor.core"]           # from ..errors import
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [("a", "b", "c")]


def test_no_import_cycles_between_fap_py_modules() -> None:
    cycles = _cycles(_import_graph())
    new = [c for c in cycles if c not in KNOWN_CYCLES]
    assert not new, f"import cycles: {new}"
    gone = [c for c in KNOWN_CYCLES if c not in cycles]
    assert not gone, f"fixed: remove from KNOWN_CYCLES: {gone}"


#: the command line: the only rooms that may import the command line
FRONT_ENDS = ("fap_py.cli", "fap_py.commands", "fap_py.__main__")


def test_no_library_room_imports_the_command_line() -> None:
    def front(mod: str) -> bool:
        return any(mod == f or mod.startswith(f + ".") for f in FRONT_ENDS)

    upward = sorted(f"{mod} -> {dep}" for mod, deps in _import_graph().items() if not front(mod)
                    for dep in deps if front(dep))
    assert not upward, upward


def test_public_import_paths_still_work() -> None:
    import importlib
    import subprocess

    code = ("import fap_py\n"
            "assert fap_py.fap.Node and fap_py.fap.RS485 and fap_py.fap.InvalidTypeError\n"
            "assert fap_py.fap.MAX_ID == 31 and fap_py.fap.classic_check and fap_py.fap.port_options\n"
            "assert fap_py.Master is fap_py.fap.Master and fap_py.RS485 is fap_py.rs485.RS485\n"
            "assert fap_py.execasync.RS485 is fap_py.RS485 and fap_py.vbus.VirtualBus\n"
            "assert fap_py.mikroc.Master and fap_py.errors.InvalidTypeError is fap_py.InvalidTypeError\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd="/")
    for name in ("Master", "Slave", "RS485", "RS485Mode", "EventKind", "Message", "SlaveEvent",
                 "Stats", "InvalidTypeError", "NotMasterError", "SlaveExistsError",
                 "UnknownSlaveError", "FapError", "ClosedError"):
        assert getattr(importlib.import_module("fap_py"), name)


# -- one stats contract: a property returning a frozen Counters snapshot -----------

#: rooms whose counters other work brings under the contract (G485's master keeps
#: a mutable attribute until its rework lands)
STATS_ELSEWHERE = ("fap_py.g485",)


def _classes_with_stats() -> List[type]:
    import importlib
    import inspect
    import pkgutil

    found = []
    for info in pkgutil.walk_packages(fap_py.__path__, "fap_py."):
        if info.name.startswith(STATS_ELSEWHERE + ("fap_py.commands", "fap_py.cli", "fap_py.__main__")):
            continue
        mod = importlib.import_module(info.name)
        for _name, cls in inspect.getmembers(mod, inspect.isclass):
            if cls.__module__ == info.name and "stats" in dir(cls):
                found.append(cls)
    return found


def test_every_stats_is_a_property() -> None:
    import inspect

    classes = _classes_with_stats()
    names = {f"{c.__module__}.{c.__qualname__}" for c in classes}
    for must in ("fap_py.fap.node.Node", "fap_py.vbus.VirtualBus", "fap_py.execasync.master.Master",
                 "fap_py.execasync.slave.Slave", "fap_py.port.Port", "fap_py.monitor.sources.LivePort",
                 "fap_py.monitor.session.Session"):
        assert must in names, must
    bad = [f"{c.__module__}.{c.__qualname__}" for c in classes
           if not isinstance(inspect.getattr_static(c, "stats"), property)
           and not c.__module__.startswith("fap_py.bridge")]   # Bridge.stats(bus): a report by name
    assert not bad, bad


def test_stats_are_frozen_snapshots_and_the_old_call_warns(tmp_path: Path) -> None:
    import dataclasses

    from fap_py import execasync, fap, mikroc
    from fap_py._stats import Counters
    from fap_py.port import Port
    from fap_py.rs485 import RS485, RS485Mode
    from fap_py.vbus import VirtualBus

    line = RS485(mode=RS485Mode.NONE)
    with VirtualBus(ports=7) as bus:
        p = bus.paths
        nodes = [bus, fap.Master(p[0], slaves=[3], rs485=line), fap.Slave(p[1], id=3, rs485=line),
                 execasync.Master(p[2], rs485=line),
                 execasync.Slave(p[3], node=1, handler=bytes, rs485=line),
                 mikroc.Master(p[4], rs485=line), mikroc.Slave(p[5], address=2, rs485=line),
                 Port(p[6], rs485=line)]
        try:
            for node in nodes:
                st = node.stats
                assert isinstance(st, Counters) and dataclasses.is_dataclass(st), node
                first = dataclasses.fields(st)[0].name
                with pytest.raises(dataclasses.FrozenInstanceError):
                    setattr(st, first, 1)
                with pytest.raises(TypeError):
                    node.stats()                          # the call form is gone (CHANGELOG.md)
                assert node.stats.as_dict().keys() == st.as_dict().keys()
        finally:
            for node in reversed(nodes):
                node.close()
