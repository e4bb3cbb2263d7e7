"""The installed package: extension built and packaged, CLI reachable."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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
    from fap_py import execasync, fap, fap_types, mikroc, vbus
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
    for kind in fap_types.EventKind:
        assert kind.value == getattr(lib, f"FAPX_EV_{kind.name}")
    for st in execasync.Status:
        assert st.value == getattr(lib, f"EXEC_ASYNC_{st.name}")
    for sr in execasync.ServeResult:
        if sr.name != "TIMEOUT":
            assert sr.value == getattr(lib, f"EXEC_SLAVE_{sr.name}")
    for mode in fap_py.RS485Mode:
        assert mode.value == getattr(lib, f"FAP_RS485_{mode.name}")
    for code, cls in mikroc._ERRORS.items():
        assert code == getattr(lib, "MIKROC_RS485_" + {
            "ChecksumError": "ECRC", "FormatError": "EFORMAT", "ShortFrameError": "ESHORT",
            "LongFrameError": "ELONG", "AbortedFrameError": "EABORT",
            "OverrunError": "EOVERRUN"}[cls.__name__])


def test_stats_dataclasses_name_every_c_counter() -> None:
    from dataclasses import fields

    from fap_py import execasync, fap_types, mikroc, port, vbus

    for cls, ctype, skip in ((fap_types.Stats, "fapx_stats", ()),
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


def test_no_import_cycles_between_fap_py_modules() -> None:
    import ast

    pkg = Path(fap_py.__file__).resolve().parent
    src = Path(__file__).resolve().parents[2] / "fap_py"
    graph = {}
    for f in src.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1 and node.module:
                deps.add(node.module.split(".")[0])
        graph[f.stem] = deps
    assert pkg.exists()

    def reach(a: str, seen: set) -> set:
        for b in graph.get(a, ()):
            if b not in seen:
                seen.add(b)
                reach(b, seen)
        return seen

    cycles = [m for m in graph if m in reach(m, set())]
    assert not cycles, cycles


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
