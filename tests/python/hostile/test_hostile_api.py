"""Hostile input to every public Python API of fap, exec async, mikroC and vbus.

Each public callable is called with arguments of the wrong type, NaN and
infinities, negative and huge numbers, a bool where an int is wanted, an int
where bytes are wanted (``bytes(300)`` would be 300 zero bytes), and after
close. The only exceptions allowed out are fap_py's own (FapError
subclasses); a generic TypeError/ValueError/OverflowError, or a hang (the
pytest timeout), fails the test.
"""
from __future__ import annotations

import asyncio
import math
from typing import Any, Callable, Dict, Iterator, List, Tuple

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fap_py import execasync, fap, mikroc
from fap_py.errors import ClosedError, FapError, InvalidTypeError, InvalidValueError
from fap_py.rs485 import RS485, RS485Mode
from fap_py.vbus import VirtualBus

pytestmark = pytest.mark.timeout(60)

LINE = RS485(mode=RS485Mode.NONE)
NAN, INF = float("nan"), float("inf")

#: Never a valid value for an int argument (IDs, addresses, counts, baud).
BAD_INTS = [True, False, -1, 2**64, -(2**70), 1.5, NAN, INF, "1", b"1", None, object(), [1]]
#: Never a valid timeout (None is valid: "wait forever", so it is not here).
BAD_TIMES = [NAN, INF, -INF, -1, -1e-9, 1e300, 10**30, True, "1", b"1", object(), [0.1]]
#: Never valid data.
BAD_DATA = [300, 0, -1, True, None, "abc", 1.5, object(), [1, 2], {1: 2}]


def expect_fap_error(fn: Callable[[], Any], label: Any = "") -> FapError:
    """Call fn; it must raise a FapError (and nothing else)."""
    try:
        result = fn()
    except FapError as exc:
        return exc
    except BaseException as exc:
        pytest.fail(f"{label}: generic {type(exc).__name__} escaped: {exc!r}")
    close = getattr(result, "close", None)
    if close is not None:
        close()
    pytest.fail(f"{label}: accepted hostile input, returned {result!r}")


@pytest.fixture(scope="module")
def bus() -> Iterator[VirtualBus]:
    with VirtualBus(ports=8) as b:
        yield b


@pytest.fixture(scope="module")
def nodes(bus: VirtualBus) -> Iterator[Dict[str, Any]]:
    objs: Dict[str, Any] = {
        "fap_master": fap.Master(bus.paths[0], slaves=[5], rs485=LINE),
        "fap_slave": fap.Slave(bus.paths[1], id=5, rs485=LINE),
        "exec_master": execasync.Master(bus.paths[2], timeout=0.01, retries=0, rs485=LINE),
        "exec_slave": execasync.Slave(bus.paths[3], node=1, handler=lambda r: r.data, rs485=LINE),
        "mik_master": mikroc.Master(bus.paths[4], rs485=LINE),
        "mik_slave": mikroc.Slave(bus.paths[5], address=7, rs485=LINE),
    }
    yield objs
    for o in objs.values():
        o.close()


# -- constructors ---------------------------------------------------------------

def ctor_cases(bus: VirtualBus) -> List[Tuple[str, Callable[[Any], Any]]]:
    p = bus.paths[6]
    return [
        ("fap.Master port", lambda v: fap.Master(v, rs485=LINE)),
        ("fap.Master baudrate", lambda v: fap.Master(p, v, rs485=LINE)),
        ("fap.Master slaves", lambda v: fap.Master(p, slaves=v, rs485=LINE)),
        ("fap.Master slave id", lambda v: fap.Master(p, slaves=[v], rs485=LINE)),
        ("fap.Master id_cycle", lambda v: fap.Master(p, id_cycle=v, rs485=LINE)),
        ("fap.Master id_answer_timeout", lambda v: fap.Master(p, id_answer_timeout=v, rs485=LINE)),
        ("fap.Master data_done_timeout", lambda v: fap.Master(p, data_done_timeout=v, rs485=LINE)),
        ("fap.Master send_budget", lambda v: fap.Master(p, send_budget=v, rs485=LINE)),
        ("fap.Master byte_gap", lambda v: fap.Master(p, byte_gap=v, rs485=LINE)),
        ("fap.Master reopen_interval", lambda v: fap.Master(p, reopen_interval=v, rs485=LINE)),
        ("fap.Master rx_queue", lambda v: fap.Master(p, rx_queue=v, rs485=LINE)),
        ("fap.Master rs485", lambda v: fap.Master(p, rs485=v)),
        ("fap.Slave id", lambda v: fap.Slave(p, id=v, rs485=LINE)),
        ("exec.Master port", lambda v: execasync.Master(v, rs485=LINE)),
        ("exec.Master baudrate", lambda v: execasync.Master(p, v, rs485=LINE)),
        ("exec.Master timeout", lambda v: execasync.Master(p, timeout=v, rs485=LINE)),
        ("exec.Master retries", lambda v: execasync.Master(p, retries=v, rs485=LINE)),
        ("exec.Slave node", lambda v: execasync.Slave(p, node=v, handler=bytes, rs485=LINE)),
        ("exec.Slave handler", lambda v: execasync.Slave(p, node=1, handler=v, rs485=LINE)),
        ("exec.Decoder buffer_size", lambda v: execasync.Decoder(v)),
        ("mikroc.Master port", lambda v: mikroc.Master(v, rs485=LINE)),
        ("mikroc.Master baudrate", lambda v: mikroc.Master(p, v, rs485=LINE)),
        ("mikroc.Slave address", lambda v: mikroc.Slave(p, address=v, rs485=LINE)),
        ("VirtualBus ports", lambda v: VirtualBus(ports=v)),
        ("VirtualBus baud", lambda v: VirtualBus(ports=2, baud=v)),
        ("VirtualBus echo", lambda v: VirtualBus(ports=2, echo=v)),
        ("VirtualBus seed", lambda v: VirtualBus(ports=2, seed=v)),
        ("RS485 mode", lambda v: RS485(mode=v)),
        ("RS485 turnaround_us", lambda v: RS485(turnaround_us=v)),
        ("RS485 exclusive", lambda v: RS485(exclusive=v)),
    ]


HOSTILE_FOR = {  # which hostile set each argument gets
    "port": [None, 3, 1.5, True, object(), "", "a\0b", [b"/dev/x"]],
    "slaves": [5, "abc", b"\x05", None, 1.5],
    "handler": [None, 3, "x"],
    "rs485": [3, "none", object(), RS485Mode.NONE],
    "echo": [1, 0, "yes", None, NAN],
    "seed": [NAN, 1.5, "1", None, True, 2**64 + 1],
}


def hostile_values(name: str) -> List[Any]:
    last = name.split()[-1]
    if last in HOSTILE_FOR:
        return HOSTILE_FOR[last]
    if any(w in last for w in ("timeout", "cycle", "budget", "gap", "interval")):
        return BAD_TIMES
    if last == "mode":
        return [True, 99, -1, "sideways", NAN]   # a mode name ("auto") is accepted
    if last == "exclusive":
        return [1, 0, "x", 1.0]
    if last in ("rx_queue", "retries", "baud", "turnaround_us"):       # None = the C default
        return [b for b in BAD_INTS if b is not None]
    return BAD_INTS


def test_constructors_refuse_hostile_arguments(bus: VirtualBus) -> None:
    for name, make in ctor_cases(bus):
        for v in hostile_values(name):
            if name == "fap.Master slave id" and v is None:
                continue
            exc = expect_fap_error(lambda: make(v), (name, v))
            assert isinstance(exc, (InvalidValueError, InvalidTypeError)), (name, v, exc)


# -- methods of open nodes ---------------------------------------------------------

def method_cases(n: Dict[str, Any]) -> List[Tuple[str, Callable[[Any], Any]]]:
    fm, fs, em, es, mm, ms = (n["fap_master"], n["fap_slave"], n["exec_master"],
                              n["exec_slave"], n["mik_master"], n["mik_slave"])
    return [
        ("fap send data", lambda v: fm.send(v, to=5)),
        ("fap send to", lambda v: fm.send(b"x", to=v)),
        ("fap send timeout", lambda v: fm.send(b"x", to=5, timeout=v)),
        ("fap slave send to", lambda v: fs.send(b"x", to=v)),
        ("fap recv timeout", lambda v: fm.recv(timeout=v)),
        ("fap wait_event timeout", lambda v: fm.wait_event(timeout=v)),
        ("fap flush timeout", lambda v: fm.flush(timeout=v)),
        ("fap add_slave id", lambda v: fm.add_slave(v)),
        ("fap remove_slave id", lambda v: fm.remove_slave(v)),
        ("fap is_active id", lambda v: fm.is_active(v)),
        ("fap wait_active timeout", lambda v: fm.wait_active([5], timeout=v)),
        ("fap arecv timeout", lambda v: asyncio.run(fm.arecv(timeout=v))),
        ("exec transact node", lambda v: em.transact(v, b"")),
        ("exec transact data", lambda v: em.transact(1, v)),
        ("exec broadcast data", lambda v: em.broadcast(v)),
        ("exec atransact node", lambda v: asyncio.run(em.atransact(v, b""))),
        ("exec atransact data", lambda v: asyncio.run(em.atransact(1, v))),
        ("exec abroadcast data", lambda v: asyncio.run(em.abroadcast(v))),
        ("exec next_seq node", lambda v: em.next_seq(v)),
        ("exec set_timeout timeout", lambda v: em.set_timeout(v)),
        ("exec set_timeout retries", lambda v: em.set_timeout(0.01, v)),
        ("exec serve timeout", lambda v: es.serve(v)),
        ("exec aserve timeout", lambda v: asyncio.run(es.aserve(v))),
        ("mikroc send address", lambda v: mm.send(v, b"")),
        ("mikroc send data", lambda v: mm.send(1, v)),
        ("mikroc receive timeout", lambda v: mm.receive(v)),
        ("mikroc areceive timeout", lambda v: asyncio.run(mm.areceive(v))),
        ("mikroc request timeout", lambda v: mm.request(1, b"", v)),
        ("mikroc slave send data", lambda v: ms.send(v)),
        ("mikroc slave receive timeout", lambda v: ms.receive(v)),
    ]


def test_methods_refuse_hostile_arguments(nodes: Dict[str, Any]) -> None:
    for name, call in method_cases(nodes):
        last = name.split()[-1]
        values = BAD_DATA if last == "data" else hostile_values(name)
        for v in values:
            exc = expect_fap_error(lambda: call(v), (name, v))
            assert isinstance(exc, (InvalidValueError, InvalidTypeError)), (name, v, exc)


def test_vbus_methods_refuse_hostile_arguments(bus: VirtualBus) -> None:
    for name, call in [
        ("set_fault port", lambda v: bus.set_fault(v)),
        ("set_fault rate", lambda v: bus.set_fault(0, bit_error_rate=v)),
        ("drop_next port", lambda v: bus.drop_next(v, 1)),
        ("drop_next n", lambda v: bus.drop_next(0, v)),
        ("corrupt_next n", lambda v: bus.corrupt_next(0, v)),
        ("silence seconds", lambda v: bus.silence(0, v)),
        ("disconnect seconds", lambda v: bus.disconnect(0, v)),
    ]:
        values = BAD_TIMES + [2.0] if name.endswith("rate") else (
            BAD_TIMES if name.endswith("seconds") else [b for b in BAD_INTS if b is not None or
                                                        not name.startswith("set_fault port")])
        for v in values:
            expect_fap_error(lambda: call(v), (name, v))


# -- calls after close ------------------------------------------------------------

def test_every_call_after_close_raises_closed(bus: VirtualBus) -> None:
    p = bus.paths[7]
    objs = [fap.Master(p, slaves=[3], rs485=LINE)]
    objs[0].close()
    objs.append(fap.Slave(p, id=3, rs485=LINE))
    objs[1].close()
    em = execasync.Master(p, rs485=LINE)
    em.close()
    es = execasync.Slave(p, node=2, handler=bytes, rs485=LINE)
    es.close()
    mm = mikroc.Master(p, rs485=LINE)
    mm.close()
    ms = mikroc.Slave(p, address=3, rs485=LINE)
    ms.close()
    vb = VirtualBus(ports=2)
    vb.close()
    fm, fs = objs
    calls = [lambda: fm.send(b"x", to=3), lambda: fm.recv(timeout=0), lambda: fm.stats, fm.fileno,
             lambda: fm.add_slave(4), lambda: fm.is_active(3), lambda: fs.recv(timeout=0),
             lambda: em.transact(1, b"x"), lambda: em.broadcast(b""), lambda: em.next_seq(1),
             lambda: em.stats, em.reopen, lambda: em.set_timeout(0.1),
             lambda: asyncio.run(em.atransact(1, b"x")), lambda: asyncio.run(em.abroadcast(b"")),
             lambda: es.serve(0), lambda: es.stats, es.start, es.fileno,
             lambda: asyncio.run(es.aserve(0.01)),
             lambda: mm.send(1, b""), lambda: mm.receive(0), lambda: mm.stats,
             lambda: asyncio.run(mm.areceive(0.01)), lambda: ms.send(b""), lambda: ms.receive(0),
             lambda: vb.drop_next(0, 1), lambda: vb.stats, lambda: vb.silence(0, 0.1)]
    for call in calls:
        assert isinstance(expect_fap_error(call), ClosedError)
    for o in objs + [em, es, mm, ms, vb]:
        o.close()          # idempotent
        assert o.closed


# -- codecs: generated input ---------------------------------------------------------

anything = st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=4),
                     st.lists(st.integers(), max_size=3), st.binary(max_size=600))


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(node=anything, data=anything, seq=anything)
def test_exec_encode_only_fap_errors(node: Any, data: Any, seq: Any) -> None:
    try:
        frame = execasync.encode(node, data, seq)
    except FapError:
        return
    assert isinstance(frame, bytes)
    assert execasync.Decoder().feed(frame)[0].data == bytes(data)


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(address=anything, data=anything, from_master=anything)
def test_mikroc_encode_only_fap_errors(address: Any, data: Any, from_master: Any) -> None:
    try:
        frame = mikroc.encode(address, data, from_master=from_master)
    except FapError:
        return
    assert mikroc.decode(frame).data == bytes(data)


@settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=anything)
def test_decoders_take_only_bytes(data: Any) -> None:
    for dec in (execasync.Decoder(), mikroc.Decoder()):
        try:
            dec.feed(data)
        except FapError:
            assert not isinstance(data, (bytes, bytearray))
        else:
            assert isinstance(data, (bytes, bytearray))


def test_decoder_feed_int_is_not_zero_bytes() -> None:
    # bytes(300) would be 300 zero bytes: an int is a type error
    for dec in (execasync.Decoder(), mikroc.Decoder()):
        assert isinstance(expect_fap_error(lambda: dec.feed(300)), InvalidTypeError)


@settings(max_examples=100, deadline=None, suppress_health_check=list(HealthCheck))
@given(fields=anything, value=anything)
def test_struct_layout_only_fap_errors(fields: Any, value: Any) -> None:
    try:
        layout = execasync.StructLayout(fields)
    except FapError:
        layout = execasync.StructLayout([("a", "u16"), ("b", "f32"), ("c", "s8", 2), ("d", "bytes", 3)])
    for call in (lambda: layout.pack(dict.fromkeys(layout.names, value)),
                 lambda: layout.unpack(value), lambda: layout.pack_native(value),
                 lambda: layout.pack(value)):
        try:
            call()
        except FapError:
            pass


def test_examples_of_issue_12() -> None:
    """The calls issue 12 names, each once, by name."""
    with VirtualBus(ports=2) as bus:
        p = bus.paths[0]
        for bad in (INF, NAN, -INF, 1e300):
            expect_fap_error(lambda: fap.Master(p, id_cycle=bad, rs485=LINE))
        expect_fap_error(lambda: execasync.Master(p, timeout="0.1", rs485=LINE))
        expect_fap_error(lambda: execasync.encode("1", b""))
        expect_fap_error(lambda: execasync.encode(1, b"", seq=1.5))
        expect_fap_error(lambda: execasync.Decoder(NAN))
        expect_fap_error(lambda: execasync.StructLayout([("a", "u8", "2")]))
        expect_fap_error(lambda: execasync.StructLayout([("a", "f32")]).pack({"a": "x"}))
        expect_fap_error(lambda: execasync.StructLayout([("a", "f64")]).pack({"a": 10**400}))
        expect_fap_error(lambda: mikroc.encode(1, b"", from_master="yes"))
        expect_fap_error(lambda: mikroc.decode(5))
        expect_fap_error(lambda: VirtualBus(ports=2, baud=1.5))
        assert math.isnan(NAN)


def test_more_entry_points(nodes: Dict[str, Any], tmp_path: Any) -> None:
    from fap_py import vbus
    from fap_py.fap.classic import classic_check
    from fap_py.rs485 import line_options, parse_realtime, port_options

    fm = nodes["fap_master"]
    layout = execasync.StructLayout([("a", "u8")])
    cases: List[Tuple[str, Callable[[Any], Any], List[Any]]] = [
        ("classic_check code", lambda v: classic_check(v, "x"), [[1], "x", None, 1.5]),
        ("port_options baudrate", lambda v: port_options(v), BAD_INTS),
        ("port_options rs485", lambda v: port_options(9600, v), HOSTILE_FOR["rs485"]),
        ("line_options rs485", line_options, HOSTILE_FOR["rs485"]),
        ("RS485.apply_to baudrate", lambda v: RS485().apply_to(None, v), [object()]),
        ("fap wait_active ids", lambda v: fm.wait_active(v, timeout=0), [5, "ab", b"\x01", 1.5, [0], [99]]),
        ("fap events timeout", lambda v: list(fm.events(v)), BAD_TIMES),
        ("fap messages timeout", lambda v: list(fm.messages(v)), BAD_TIMES),
        ("fap await_event timeout", lambda v: asyncio.run(fm.await_event(v)), BAD_TIMES),
        ("exec unpack", layout.unpack, BAD_DATA + [b"\x01\x02"]),
        ("exec unpack_native", layout.unpack_native, BAD_DATA + [b"\x01\x02"]),
        ("exec pack_native", layout.pack_native, BAD_DATA + [b"\x01\x02"]),
        ("exec pack", layout.pack, BAD_DATA + [{"a": 256}, {"a": -1}, {"a": True}, {"b": 1}]),
        ("vbus parse_capture", vbus.parse_capture, [5, None, [5], b"x", ["1 x zz"]]),
        ("vbus read_capture", vbus.read_capture, [5, None, 1.5, str(tmp_path / "missing")]),
        ("parse_realtime spec", parse_realtime,
         [5, None, b"fifo:5", "fifo:0", "fifo:\udcff", "a\0", "x" * 100000, "cpu=99999999999"]),
        ("RS485 realtime", lambda v: RS485(realtime=v), [5, b"rr:1", "rr:0", "mlock,mlock"]),
        ("VirtualBus realtime", lambda v: vbus.VirtualBus(ports=2, realtime=v), [5, "cpu=63-64"]),
    ]
    for name, call, values in cases:
        for v in values:
            expect_fap_error(lambda: call(v), (name, v))


def test_async_pump_waits_refuse_hostile_timeouts(nodes: Dict[str, Any]) -> None:
    """The pump behind arecv/await_event checks its own timeouts (it is public too)."""
    from fap_py.fap.aio import AsyncPump

    fm = nodes["fap_master"]

    async def bad(v: Any, which: str) -> None:
        pump = AsyncPump(fm, asyncio.get_running_loop())
        try:
            await getattr(pump, which)(v)
        finally:
            pump.stop()

    for which in ("get_rx", "get_event"):
        for v in BAD_TIMES:
            exc = expect_fap_error(lambda: asyncio.run(bad(v, which)), (which, v))
            assert isinstance(exc, (InvalidValueError, InvalidTypeError)), (which, v, exc)


#: Every public callable that takes arguments, as "owner.name"; the test
#: below fails when one is added without a hostile case here.
COVERED = {
    "fap.classic_check", "fap.port_options", "rs485.port_options", "rs485.line_options",
    "rs485.parse_realtime",
    "RS485.apply_to", "Node.send", "Node.flush", "Node.recv", "Node.messages", "Node.wait_event",
    "Node.events", "Node.arecv", "Node.await_event", "Node.aevents", "Master.add_slave",
    "Master.remove_slave", "Master.is_active", "Master.wait_active", "Slave.send",
    "execasync.encode", "Decoder.feed", "StructLayout.pack_native", "StructLayout.unpack_native",
    "StructLayout.pack", "StructLayout.unpack", "Master.set_timeout", "Master.transact",
    "Master.broadcast", "Master.atransact", "Master.abroadcast", "Master.next_seq", "Slave.serve", "Slave.aserve", "mikroc.encode",
    "mikroc.decode", "Master.send", "Master.receive", "Master.areceive", "Master.arequest",
    "Master.request", "Slave.receive", "Slave.areceive", "VirtualBus.set_fault",
    "VirtualBus.drop_next", "VirtualBus.corrupt_next", "VirtualBus.silence",
    "VirtualBus.disconnect", "vbus.parse_capture", "vbus.read_capture", "Capture.data_from",
    "Capture.events_of", "classic.classic_check", "AsyncPump.get_rx", "AsyncPump.get_event",
    # --- sim: fap_py.sim's public functions and clock (test_sim_entry_points_refuse_hostile) ---
    "sim.load", "sim.loads", "sim.plugin", "sim.plugin_name", "ManualClock.advance",
    # --- end sim ---
    # --- web: fap_py.web's sources (test_web_sources_refuse_hostile_arguments) ---
    "Source.run", "Source.add_fault", "Source.remove_fault", "PortSource.run", "CaptureSource.run",
    "SimSource.run", "SimSource.add_fault", "SimSource.remove_fault", "SimControlSource.run",
    "SimControlSource.add_fault", "SimControlSource.remove_fault", "MqttSource.run",
    # --- end web ---
}


# --- web ---
def test_web_sources_refuse_hostile_arguments(tmp_path: Any) -> None:
    """fap_py.web's sources (defined in a private module, public through fap_py.web):
    run(), add_fault(), remove_fault() refuse bad values with the package's errors."""
    import threading

    from fap_py.errors import FapError
    from fap_py.web import CaptureSource, MqttSource, PortSource, SimControlSource, SimSource, Source
    from fap_py.web._hub import Hub

    cap = tmp_path / "b.cap"
    cap.write_text("# fap-vbus-capture 1 ports=2 baud=9600\n0 0 01 02\n")
    site = {"bus": [{"protocol": "exec", "node": [{"address": 1}]}]}
    sim = SimSource(site)
    sim.open()
    try:
        bridge = tmp_path / "bridge.toml"
        bridge.write_text(f'[broker]\nurl = "mqtt://127.0.0.1:1"\n[bridge]\nhost = "h"\nstate_dir = "{tmp_path}"\n'
                          '[[bus]]\nname = "ex"\nport = "/nonexistent/p"\nprotocol = "exec"\nnodes = [5]\n')
        sources = [Source(), PortSource("/nonexistent/port", 9600), CaptureSource(str(cap)), sim,
                   SimControlSource(f"unix:{tmp_path}/nobody.sock", str(cap), timeout=0.5), MqttSource(str(bridge))]
        for bad in ((None,), (str(tmp_path / "missing.toml"),), (str(bridge), 5), (str(bridge), "nope")):
            with pytest.raises(FapError):
                MqttSource(*bad)
        hub, stop = Hub(10), threading.Event()
        stop.set()
        for src in sources:
            for bad_hub, bad_stop in ((None, stop), ("hub", stop), (hub, None), (hub, True), (hub, lambda: 1)):
                with pytest.raises(FapError):
                    src.run(bad_hub, bad_stop)
            for bad in (None, 1, "off", b"x", [], {"kind": None}, {"kind": "melt"}, {"kind": "off", "x": 1},
                        {"kind": "off", "node": "x"}, {"kind": "off", "probability": 2.0},
                        {"kind": "late_reply", "ms": "x"}, {"kind": "off", "bus": 5}):
                with pytest.raises(FapError):
                    src.add_fault(bad)
            for bad in (None, "x", 1.5, True, [], b"1"):
                with pytest.raises(FapError):
                    src.remove_fault(bad)
        with pytest.raises(FapError):          # before open(): said so, not an AttributeError
            CaptureSource(str(cap)).run(hub, stop)
        for bad in ((None, str(cap)), ("tcp://x", str(cap)), ("unix:", str(cap)), ("unix:/a\0b", str(cap)),
                    (f"unix:{tmp_path}/s", None), (f"unix:{tmp_path}/s", 5)):
            with pytest.raises(FapError):
                SimControlSource(*bad)
        with pytest.raises(FapError):          # nobody answers there: a FileError naming the socket
            SimControlSource(f"unix:{tmp_path}/nobody.sock", str(cap)).open()
        assert sim.sim.faults_list() == []
    finally:
        sim.close()


# --- sim ---
def test_sim_entry_points_refuse_hostile_arguments(tmp_path: Any) -> None:
    """fap_py.sim's public API refuses bad values with the package's errors."""
    from fap_py import sim

    good = '[[bus]]\nprotocol = "exec"\n[[bus.node]]\naddress = 1\n'
    clock = sim.ManualClock()
    cases: List[Tuple[str, Callable[[Any], Any], List[Any]]] = [
        ("sim.load path", sim.load, [5, None, 1.5, b"", "", "a\0", [1], str(tmp_path)]),
        ("sim.loads text", sim.loads, [5, None, b"x", [1], "[[bus]]", "x = ["]),
        ("sim.loads name", lambda v: sim.loads(good, v), [5, None, b"n"]),
        ("sim.loads fmt", lambda v: sim.loads(good, "<c>", v), [5, None, "ini", ""]),
        ("sim.plugin protocol", sim.plugin, [5, None, b"exec", "nope", ""]),
        ("sim.plugin_name protocol", sim.plugin_name, [5, None, b"exec", "nope"]),
        ("ManualClock.advance dt", clock.advance, [NAN, INF, -1, "1", None, True, 10**400]),
        ("ManualClock t", sim.ManualClock, [NAN, -1, "0", None]),
        ("FastClock speed", sim.FastClock, [0, -1, NAN, INF, "10", None]),
        ("Sim config", sim.Sim, [5, None, [], {}, {"bus": 5}, {"bus": [{"protocol": "x"}]}]),
        ("Sim port", lambda v: sim.Sim(sim.loads(good), port=v), [5, "", "a\0", 1.5]),
        ("Sim baud", lambda v: sim.Sim(sim.loads(good), baud=v), [-1, 0, 1.5, "9600", True]),
        ("Sim clock", lambda v: sim.Sim(sim.loads(good), clock=v), [5, "now", object()]),
    ]
    for name, call, values in cases:
        for v in values:
            expect_fap_error(lambda: call(v), (name, v))
    assert clock.now() == 0.0
# --- end sim ---


def _public_modules() -> Iterator[Any]:
    """Every public module under fap_py (``pkgutil.walk_packages``: no list to keep)."""
    import importlib
    import pkgutil

    import fap_py

    yield fap_py
    for info in pkgutil.walk_packages(fap_py.__path__, "fap_py."):
        if not any(part.startswith("_") for part in info.name.split(".")[1:]):
            yield importlib.import_module(info.name)


def _takes_arguments(fn: Any, bound: bool) -> bool:
    import inspect

    try:
        return len(inspect.signature(fn).parameters) > (1 if bound else 0)
    except (TypeError, ValueError):
        return False


def test_every_public_callable_with_arguments_has_a_hostile_case(walk_report: dict) -> None:
    """Every public function and method under fap_py that takes arguments is called
    with bad values: by a case of this file (COVERED) or by the generic walk
    (walk_runner.py, which reports what it called). A class's method counts as
    walked when the walk called it on the class or on a subclass."""
    import inspect

    walked = set(walk_report["walked"])
    excluded = tuple(walk_report["excluded"])   # each with its reason in walk_runner.py
    missing = []
    modules = list(_public_modules())   # all imported first: a subclass in a later module counts
    for mod in modules:
        if mod.__name__.startswith(excluded):
            continue
        short = mod.__name__.split(".")[-1]
        names = getattr(mod, "__all__", None)
        if names is None:       # no __all__: every public name the module defines
            names = [n for n, o in vars(mod).items()
                     if not n.startswith("_") and getattr(o, "__module__", None) == mod.__name__]
        for name in names:
            obj = getattr(mod, name)
            where = f"{getattr(obj, '__module__', '')}.{getattr(obj, '__qualname__', name)}"
            if inspect.isfunction(obj) and _takes_arguments(obj, False):
                if f"{short}.{name}" not in COVERED and name != "c_defaults" and where not in walked:
                    missing.append(where)
            elif inspect.isclass(obj) and not issubclass(obj, BaseException) \
                    and obj.__module__.startswith("fap_py") \
                    and not getattr(obj, "_is_protocol", False):   # a typing.Protocol: no code
                owners = [obj] + _subclasses(obj)
                for m, v in vars(obj).items():
                    if m.startswith("_") or not inspect.isfunction(v) or not _takes_arguments(v, True):
                        continue
                    if f"{name}.{m}" in COVERED:
                        continue
                    if not any(f"{c.__module__}.{c.__qualname__}.{m}" in walked for c in owners):
                        missing.append(f"{where}.{m}")
    assert not missing, sorted(set(missing))


def _subclasses(cls: type) -> List[type]:
    out = []
    for sub in cls.__subclasses__():
        out += [sub] + _subclasses(sub)
    return out


# -- room "hrest": the bridge's outputs interface (fap_py.bridge.outputs) ----------------
# BridgeView's methods and OutputBase's default hooks, called with hostile values on a
# real Bridge that is never started (its broker is nobody's port 1: nothing connects,
# no bus opens). fap_py.port and fap_py.progress are covered by the walk (walk_runner.py).

COVERED |= {
    "BridgeView.node", "BridgeView.output", "BridgeView.publish_now",
    "OutputBase.start", "OutputBase.on_connect", "OutputBase.on_node_event", "OutputBase.on_message",
}


@pytest.fixture
def bridge_view(tmp_path: Any) -> Iterator[Any]:
    from fap_py.bridge import Bridge
    from fap_py.bridge.config import from_dict
    from fap_py.bridge.outputs import BridgeView

    with VirtualBus(ports=2) as vb:
        cfg = from_dict({"broker": {"url": "mqtt://127.0.0.1:1"},
                         "bridge": {"host": "hostile", "state_dir": str(tmp_path / "state")},
                         "bus": [{"name": "b", "port": vb.paths[0], "protocol": "exec", "nodes": [1]}]})
        bridge = Bridge(cfg)
        yield bridge, BridgeView(bridge)


BAD_NAMES = [None, 5, 1.5, True, b"b", object(), ["b"], "", "a\0b", "x" * 1000]


def test_bridge_view_refuses_hostile_arguments(bridge_view: Any) -> None:
    from fap_py.bridge.outputs import NodeView

    bridge, view = bridge_view
    assert isinstance(view.node("b", 1), NodeView) and view.node("b", 1).node == 1
    assert view.output("nope") is None
    view.publish_now("fap/x", b"", False)        # not connected: nothing, and no error
    cases: List[Tuple[str, Callable[[Any], Any], List[Any]]] = [
        ("node bus", lambda v: view.node(v, 1), BAD_NAMES + ["nobus"]),
        ("node node", lambda v: view.node("b", v), BAD_INTS + [256]),
        ("output name", view.output, BAD_NAMES),
        ("publish_now topic", lambda v: view.publish_now(v, b"x"),
         BAD_NAMES[:7] + ["a\0b", "a/+/b", "a/#", "\udcff", "x" * 70000]),
        ("publish_now payload", lambda v: view.publish_now("fap/x", v), BAD_DATA),
        ("publish_now retain", lambda v: view.publish_now("fap/x", b"x", v), [1, 0, "yes", None, NAN]),
    ]
    for name, call, values in cases:
        for v in values:
            exc = expect_fap_error(lambda: call(v), (name, v))
            assert isinstance(exc, (InvalidValueError, InvalidTypeError)), (name, v, exc)
    exc = expect_fap_error(lambda: view.node("nobus", 1))
    assert "nobus" in str(exc) and "b" in str(exc)       # names the known buses


def test_output_base_hooks_refuse_hostile_arguments(bridge_view: Any) -> None:
    from fap_py.bridge.outputs import SEEN, NodeEvent, OutputBase

    bridge, view = bridge_view
    out = OutputBase()
    out.start(view)
    assert out.ctx is view
    nv, ev = view.node("b", 1), NodeEvent(SEEN, "b", 1)
    out.on_connect(bridge.link)
    out.on_node_event(nv, ev)
    out.on_message("fap/x", b"x")
    junk = [None, 5, "x", object(), bridge]
    cases: List[Tuple[str, Callable[[Any], Any], List[Any]]] = [
        ("start ctx", out.start, junk),
        ("on_connect link", out.on_connect, junk + [view]),
        ("on_node_event view", lambda v: out.on_node_event(v, ev), junk + [ev]),
        ("on_node_event event", lambda v: out.on_node_event(nv, v), junk + [nv]),
        ("on_message topic", lambda v: out.on_message(v, b"x"), [None, 5, b"t", object()]),
        ("on_message payload", lambda v: out.on_message("fap/x", v), BAD_DATA),
    ]
    for name, call, values in cases:
        for v in values:
            exc = expect_fap_error(lambda: call(v), (name, v))
            assert isinstance(exc, InvalidTypeError), (name, v, exc)
# -- end of room "hrest" ------------------------------------------------------------------
