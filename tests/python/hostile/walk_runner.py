"""The hostile walk: every public callable of every fap_py module, bad values in.

Run by ``test_walk.py`` in a child process (its own cwd, HOME and stdin, so a
call that writes files, reads stdin or leaves a thread behind cannot touch
the test run); prints one JSON report on stdout.

What is walked: ``pkgutil.walk_packages`` over fap_py (subpackages included),
minus the modules in :data:`EXCLUDED` (each with its reason). In each module,
every public function and class defined there; for a class its constructor
and every public method (an instance comes from :data:`FACTORIES`, or is
built from valid values by annotation; a class with public methods and
neither is reported, so a new class cannot escape).

Each parameter gets the bad values its annotation calls for (:func:`bad_values`)
while the others hold valid ones; each call runs in a worker thread bounded
by :data:`CALL_TIMEOUT`. A finding is one of:

* ``generic``: an exception that is not a fap_py.errors class escaped;
* ``hang``: the call did not return within CALL_TIMEOUT;
* ``accepted``: a value the table says is bad came back without an error;
* ``bytes_like``: bytes were taken but a bytearray or a strided memoryview of
  the same bytes was not (or the other way round).
"""
from __future__ import annotations

import asyncio
import importlib
import inspect
import io
import json
import os
import pkgutil
import re
import sys
import tempfile
import threading
import time
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple

import fap_py
from fap_py.errors import FapError

CALL_TIMEOUT = 5.0
NAN, INF = float("nan"), float("inf")

#: modules not walked, and why
EXCLUDED = {
    "fap_py.__main__": "runs the command line on import",
    "fap_py.commands": "argparse front ends: add_parser(sub) and run_*(Namespace); they are "
                       "reached through fap_py.cli.main, whose argv the CLI's random-argv test walks",
    "fap_py.cli": "the command line itself: main(argv) takes argv strings (the CLI's random-argv "
                  "test), setup_logging is its -v handling",
    "fap_py.soak": "the fault soak engine behind `fap soak` (it lived in fap_py.commands): run(cfg) "
                   "soaks for cfg.seconds with slave processes, child() is a slave process's body "
                   "that runs until it is killed; reached through `fap soak`, whose argv the "
                   "random-argv test walks, and tests/python/cli/test_soak*.py",
    # --- sim (fap sim) ---
    "fap_py.sim.protocols": "the sim's per-protocol plug-ins, found by name through the protocol "
                            "table's TOOLS['sim'] room: check_node/make_node/start/... are called "
                            "by fap_py.sim.Sim with a config that fap_py.sim.load already checked "
                            "(the sim's internals, not user API); reached through fap_py.sim.Sim "
                            "(walked), `fap sim` (the random-argv test) and tests/python/sim",
    # --- end sim ---
}

#: functions that are C callbacks (cffi ``extern "Python"``): called by C with C data,
#: named for C, never by Python code
C_CALLBACK = re.compile(r"^fap_py_")

#: classes whose methods are not walked on an instance of their own, and why
NO_INSTANCE = {
    "fap_py.fap.node.Node": "the base of fap.Master and fap.Slave: its methods are walked on those",
    "fap_py.fap.aio.AsyncPump": "the asyncio pump behind Node.arecv/await_event/aevents (walked "
                                "there); its methods run only inside the loop it belongs to",
    "fap_py.bridge.buses.BusAdapter": "the base of the four bus adapters: its methods are walked "
                                      "on those",
    "fap_py.bridge.buses.Sink": "a typing.Protocol (what an adapter reports to, the Bridge): no "
                                "instances",
    "fap_py.monitor.decoders.Decoder": "the base of the four decoders: its methods are walked on "
                                       "those",
}

#: parameters that are free text in a message (any value prints), per callable
LABELS = {
    "fap_py.errors.error_from_code": {"what", "path"},
    "fap_py.port.port_error": {"what", "path"},
    "fap_py.g485.master.ReplyWaiter.expired": {"timeout"},   # the timeout waited, for the text
}

TIME_NAMES = re.compile(r"timeout|seconds|interval|gap|cycle|budget|delay|idle|wait|period|duration"
                        r"|^t$|^s$|char_s")


class Sentinel:
    """An object no API accepts as anything."""

    def __repr__(self) -> str:
        return "<object>"


OBJ = Sentinel()


def _strip_optional(ann: str) -> Tuple[str, bool]:
    a = ann.replace(" ", "")
    optional = False
    m = re.fullmatch(r"Optional\[(.*)\]", a)
    if m:
        a, optional = m.group(1), True
    if a.endswith("|None"):
        a, optional = a[:-5], True
    if a.startswith("Union[") and a.endswith(",None]"):
        a, optional = "Union[" + a[6:-6] + "]", True
    return a, optional


def kind_of(name: str, ann: str) -> str:
    """The value category of a parameter, from its annotation and name."""
    a, _ = _strip_optional(ann)
    if a in ("bytes", "BytesLike", "Union[bytes,bytearray,memoryview]"):
        return "bytes"
    if a == "Data":
        return "data"
    if a in ("PathLike", "PortSpec", "Union[str,'os.PathLike[str]']", "Union[str,os.PathLike]") \
            or name in ("path", "link_dir", "capture", "eeprom_path"):
        return "path"
    if a == "int":
        return "int"
    if a == "float" or (a in ("int|float", "Union[int,float]")):
        return "time" if TIME_NAMES.search(name) else "float"
    if a == "bool":
        return "bool"
    if a == "str":
        return "str"
    if a.startswith("Callable") or name in ("handler", "on_apply", "callback"):
        return "callable"
    if a in ("Iterable[int]", "List[int]", "Sequence[int]"):
        return "ints"
    return "any"


def optional_param(p: inspect.Parameter) -> bool:
    return _strip_optional(str(p.annotation))[1] or p.default is None


#: values that are wrong for every parameter of a kind (ranges are per
#: parameter: test_hostile_api.py)
BAD = {
    "int": [True, 1.5, NAN, "1", b"1", OBJ, [1]],
    "time": [NAN, INF, -INF, -1, 1e300, True, "1", OBJ, [0.1]],
    "float": [NAN, True, "1", OBJ, [0.1]],
    "bytes": [300, 1.5, "abc", OBJ, {1: 2}],
    "data": [1.5, "abc", OBJ, {1: 2}],
    "path": ["", "a\0b", 1.5, OBJ, [b"/dev/x"]],
    "bool": ["yes", 2, 1.5, OBJ],
    "str": [5, 1.5, OBJ],
    "callable": [3, "x"],
    "ints": [5, OBJ, [OBJ], "ab"],
    "any": [OBJ],
}
#: kinds whose bad values must be refused (not only without a generic exception)
MUST_REFUSE = {"int", "time", "float", "bytes", "data", "path", "bool", "str", "callable", "ints"}


def bad_values(p: inspect.Parameter, where: str = "") -> List[Any]:
    kind = "any" if p.name in LABELS.get(where, ()) else kind_of(p.name, str(p.annotation))
    values = list(BAD[kind])
    if not optional_param(p) and kind != "any":
        values.append(None)
    return values


class Ctx:
    """Valid values the walk hands to the parameters not under test."""

    def __init__(self) -> None:
        from fap_py.rs485 import RS485, RS485Mode
        from fap_py.vbus import VirtualBus

        self.line = RS485(mode=RS485Mode.NONE)
        self.bus = VirtualBus(ports=24)
        self._next = 0
        self.keep: List[Any] = []    # buses of the factories' instances

    def port(self) -> str:
        """A fresh bus port for each object that opens one (exclusive locks)."""
        p = self.bus.paths[self._next % len(self.bus.paths)]
        self._next += 1
        return p

    def valid(self, p: inspect.Parameter) -> Any:
        kind = kind_of(p.name, str(p.annotation))
        if p.default is not inspect.Parameter.empty:
            if kind == "time" or TIME_NAMES.search(p.name):
                return 0.01           # never "wait forever" beside the value under test
            return p.default
        ann = str(p.annotation)
        if "RS485" in ann:
            return self.line
        return {"int": 1, "time": 0.01, "float": 0.5, "bytes": b"\x01", "data": b"\x01",
                "path": self.port(), "bool": False, "str": "x", "callable": lambda *a: None,
                "ints": [1], "any": None}[kind]


def factories(ctx: Ctx) -> Dict[str, Callable[[], Any]]:
    """Instances whose methods are walked (classes the walk cannot build alone)."""
    from fap_py import execasync, fap, mikroc, vbus
    from fap_py.bridge import buses
    from fap_py.bridge.bridge import Bridge
    from fap_py.bridge.homeassistant import Discovery
    from fap_py.bridge.mqtt import MqttLink
    from fap_py.bridge.sparkplug import SparkplugNode
    from fap_py.bridge.store import Store
    from fap_py.g485.aio import AsyncG485Master
    from fap_py.g485.codec import reply_prefix
    from fap_py.g485.device import SimDevice
    from fap_py.g485.master import G485Master, ReplyWaiter
    from fap_py.g485.simulator import Simulator
    from fap_py.g485.transaction import Session
    from fap_py.g485.transport import PortIO, SerialIO
    from fap_py.monitor.decoders import CodecDecoder
    from fap_py.monitor.pcap import PcapWriter
    from fap_py.monitor.sources import LivePort
    from fap_py.port import Port

    line = ctx.line

    class Sink:
        """What a bus adapter reports to: drops everything."""

        def rx(self, *a: Any) -> None: ...
        def rx_many(self, *a: Any) -> None: ...
        def state(self, *a: Any) -> None: ...
        def error(self, *a: Any) -> None: ...

    def adapter(protocol: str, **keys: Any) -> Any:
        """A bus adapter (the protocol's bridge plug-in) on a bus of its own, not opened."""
        from fap_py.bridge.config import bus_from_dict
        return buses.make_adapter(bus_from_dict(dict({"name": "b", "port": own(), "protocol": protocol},
                                                     **keys)), Sink())

    def bridge_config() -> Any:
        """A bridge on one bus of its own (not opened), a broker nobody listens on (never
        connected: nothing here starts), Sparkplug and Home Assistant on."""
        from fap_py.bridge.config import BridgeConfig, BrokerConfig, SparkplugConfig, bus_from_dict
        bus = bus_from_dict({"name": "b", "port": own(), "protocol": "exec", "nodes": [1],
                             "homeassistant": True, "sparkplug": True})
        return BridgeConfig(broker=BrokerConfig(host="127.0.0.1", port=1, tls=False),
                            buses=(bus,), host="walk", state_dir=tempfile.mkdtemp(),
                            sparkplug=SparkplugConfig("g", "e"))

    def web_server() -> Any:
        from fap_py.web import CaptureSource, WebServer

        path = os.path.join(tempfile.mkdtemp(), "b.cap")
        with open(path, "w") as fh:
            fh.write("# fap-vbus-capture 1 ports=2 baud=9600\n0 0 01 02\n")
        server = WebServer(CaptureSource(path), port=0)
        ctx.keep.append(server)
        return server

    def own() -> str:
        """A port of a bus of its own: the instance keeps it while its methods are walked."""
        bus = vbus.VirtualBus(ports=2)
        ctx.keep.append(bus)
        return bus.paths[0]

    def served(protocol: str, **kw: Any) -> str:
        """A daemon (fap_py.serve) on a bus of its own, in a thread of the walk: its URL."""
        import asyncio
        import threading

        from fap_py.serve import Daemon, ServeConfig
        where = tempfile.mkdtemp()
        cfg = ServeConfig(protocol, own(), [f"unix:{where}/s.sock"], rs485=line, lock_dir=where,
                          timeout=0.01, retries=0, **kw)
        up = threading.Event()

        async def main() -> None:
            d = Daemon(cfg)
            await d.start()
            up.set()
            await d.wait_closed()

        threading.Thread(target=asyncio.run, args=(main(),), daemon=True).start()
        up.wait(10)
        return f"fapd://{where}/s.sock"
    return {
        # --- serve (fap serve): clients of a daemon in a thread of the walk ---
        "fap_py.execasync.daemon.DaemonMaster": lambda: execasync.Master(served("exec"), timeout=0.01,
                                                                  retries=0),
        "fap_py.mikroc.daemon.DaemonMaster": lambda: mikroc.Master(served("mikroc")),
        "fap_py.fap.daemon.DaemonFapMaster": lambda: fap.Master(served("fap", slaves=[5]), slaves=[5]),
        "fap_py.g485.daemon.DaemonG485Master": lambda: __import__("fap_py.g485", fromlist=["G485Master"]).G485Master(
            served("g485"), timeout=0.01),
        "fap_py.serve.Connection": lambda: __import__("fap_py.serve", fromlist=["Connection"]).Connection(
            served("raw")),
        # --- end serve ---
        "fap_py.fap.master.Master": lambda: fap.Master(own(), slaves=[5], rs485=line),
        "fap_py.fap.slave.Slave": lambda: fap.Slave(own(), id=5, rs485=line),
        "fap_py.execasync.master.Master": lambda: execasync.Master(own(), timeout=0.01, retries=0,
                                                            rs485=line),
        "fap_py.execasync.slave.Slave": lambda: execasync.Slave(own(), node=1,
                                                          handler=lambda r: r.data, rs485=line),
        "fap_py.execasync.layout.StructLayout": lambda: execasync.StructLayout([("a", "u8"), ("b", "f32")]),
        "fap_py.mikroc.master.Master": lambda: mikroc.Master(own(), rs485=line),
        "fap_py.mikroc.slave.Slave": lambda: mikroc.Slave(own(), address=7, rs485=line),
        "fap_py.vbus.VirtualBus": lambda: vbus.VirtualBus(ports=2),
        "fap_py.port.Port": lambda: Port(own(), rs485=line),
        "fap_py.g485.master.G485Master": lambda: G485Master(own(), timeout=0.01, retries=0,
                                                            rs485=line),
        "fap_py.g485.aio.AsyncG485Master": lambda: AsyncG485Master(own(), timeout=0.01,
                                                                   retries=0, rs485=line),
        "fap_py.g485.simulator.Simulator": lambda: Simulator(own(), [SimDevice(3)], rs485=line),
        "fap_py.g485.device.SimDevice": lambda: SimDevice(3),
        "fap_py.g485.master.ReplyWaiter": lambda: ReplyWaiter(
            G485Master(own(), timeout=0.01, retries=0, rs485=line), reply_prefix(8, 3)),
        "fap_py.g485.transaction.Transaction": lambda: Session(timeout=0.01, retries=0).read(1, 8),
        "fap_py.g485.transport.PortIO": lambda: PortIO(own(), 115200, line),
        "fap_py.g485.transport.SerialIO": lambda: SerialIO("loop://", 115200),
        "fap_py.bridge.protocols.fap.Adapter": lambda: adapter("fap", slaves=[5]),
        "fap_py.bridge.protocols.exec.Adapter": lambda: adapter("exec", nodes=[1]),
        "fap_py.bridge.protocols.mikroc.Adapter": lambda: adapter("mikroc", nodes=[1]),
        "fap_py.bridge.protocols.g485.Adapter": lambda: adapter("g485", device=[]),
        "fap_py.bridge.polled.PolledAdapter": lambda: adapter("exec", nodes=[1]),
        "fap_py.bridge.store.Store": lambda: Store(os.path.join(tempfile.mkdtemp(), "s.sqlite")),
        "fap_py.bridge.mqtt.MqttLink": lambda: MqttLink(bridge_config(), Store(
            os.path.join(tempfile.mkdtemp(), "s.sqlite")), lambda *a: None),
        "fap_py.bridge.homeassistant.Discovery": lambda: Discovery(bridge_config(),
                                                                   lambda *a: None),
        "fap_py.bridge.sparkplug.SparkplugNode": lambda: SparkplugNode(bridge_config(), list),
        "fap_py.bridge.bridge.Bridge": lambda: Bridge(bridge_config()),
        "fap_py.monitor.pcap.PcapWriter": lambda: PcapWriter(io.BytesIO()),
        "fap_py.monitor.sources.LivePort": lambda: LivePort(own(), 9600),
        "fap_py.monitor.decoders.CodecDecoder": lambda: CodecDecoder("fap", 9600),
        # --- sim: one exec node on a virtual bus of its own (closed after the walk) ---
        "fap_py.sim.Sim": lambda: __import__("fap_py.sim", fromlist=["Sim"]).Sim(
            __import__("fap_py.sim", fromlist=["loads"]).loads(
                '[[bus]]\nprotocol = "exec"\n[[bus.node]]\naddress = 1\n')),
        # --- end sim ---
        # --- web: a server over a two-byte capture, not started (start() is walked) ---
        "fap_py.web.WebServer": lambda: web_server(),
    }


def public_callables() -> Iterator[Tuple[str, str, Any, Optional[type]]]:
    """(module, qualified name, callable, owning class or None) of every public callable."""
    for info in sorted(pkgutil.walk_packages(fap_py.__path__, "fap_py."), key=lambda i: i.name):
        name = info.name
        parts = name.split(".")
        if any(p.startswith("_") for p in parts[1:]) and name not in EXCLUDED:
            continue          # private modules are not API
        if any(name == e or name.startswith(e + ".") for e in EXCLUDED):
            continue
        mod = importlib.import_module(name)
        for attr, obj in sorted(vars(mod).items()):
            if attr.startswith("_") or getattr(obj, "__module__", None) != name:
                continue
            if inspect.isfunction(obj):
                if not C_CALLBACK.match(attr):
                    yield name, f"{name}.{attr}", obj, None
            elif inspect.isclass(obj):
                yield name, f"{name}.{attr}", obj, obj


def is_record(cls: type) -> bool:
    """Enums, exceptions, NamedTuples and dataclasses: plain values, no checks by design."""
    import dataclasses
    import enum
    return (issubclass(cls, (enum.Enum, BaseException)) or dataclasses.is_dataclass(cls)
            or (issubclass(cls, tuple) and hasattr(cls, "_fields")))


def methods_of(cls: type) -> Iterator[Tuple[str, Any]]:
    seen = set()
    for klass in cls.__mro__:
        if not klass.__module__.startswith("fap_py"):
            continue
        for attr, obj in vars(klass).items():
            if attr.startswith("_") or attr in seen:
                continue
            seen.add(attr)
            if inspect.isfunction(obj):
                yield attr, obj


def run_bounded(fn: Callable[[], Any]) -> Tuple[str, Any]:
    """("ok", result) / ("raised", exc) / ("hang", None)."""
    box: List[Tuple[str, Any]] = []

    def target() -> None:
        try:
            result = fn()
            if inspect.iscoroutine(result):
                result = asyncio.run(asyncio.wait_for(result, CALL_TIMEOUT - 1))
            elif inspect.isasyncgen(result):
                async def first() -> Any:
                    return await result.__anext__()
                result = asyncio.run(asyncio.wait_for(first(), CALL_TIMEOUT - 1))
            elif inspect.isgenerator(result):
                result = next(result, None)
            box.append(("ok", result))
        except BaseException as exc:  # classified by the caller
            box.append(("raised", exc))
    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(CALL_TIMEOUT)
    if t.is_alive():
        return "hang", None
    return box[0]


def close_quietly(obj: Any) -> None:
    aclose = getattr(obj, "aclose", None)
    if callable(aclose) and not inspect.isclass(obj) and not hasattr(obj, "close"):
        run_bounded(aclose)
        return
    close = getattr(obj, "close", None)
    if callable(close) and not inspect.isclass(obj):
        try:
            run_bounded(close)
        except Exception:
            pass


def show(v: Any) -> str:
    try:
        r = repr(v)
    except Exception as exc:  # a repr that fails on the bad value it holds
        r = f"<{type(v).__name__}: repr raised {type(exc).__name__}>"
    return r if len(r) < 40 else r[:37] + "..."


def signature(fn: Any) -> Optional[inspect.Signature]:
    try:
        return inspect.signature(fn)
    except (TypeError, ValueError):
        return None


def walk() -> Dict[str, Any]:
    ctx = Ctx()
    facts = factories(ctx)
    findings: List[Dict[str, str]] = []
    calls = 0
    callables = 0
    modules = set()
    walked: set = set()      # every callable called with bad values, by qualified name

    def note(where: str, param: str, value: Any, kind: str, detail: str) -> None:
        findings.append({"callable": where, "param": param, "value": show(value), "kind": kind,
                         "detail": detail[:200]})

    def outcome(where: str, p: inspect.Parameter, value: Any, call: Callable[[], Any],
                must_refuse: bool) -> Tuple[str, Any]:
        nonlocal calls
        calls += 1
        status, got = run_bounded(call)
        if status == "hang":
            note(where, p.name, value, "hang", f"no return within {CALL_TIMEOUT} s")
        elif status == "raised" and not isinstance(got, FapError):
            note(where, p.name, value, "generic", f"{type(got).__name__}: {got}")
        elif status == "ok":
            if must_refuse:
                note(where, p.name, value, "accepted", f"returned {show(got)}")
            close_quietly(got)
        return status, got

    def walk_callable(where: str, fn: Callable[..., Any], params: List[inspect.Parameter]) -> None:
        nonlocal callables, calls
        callables += 1
        walked.add(where)
        for p in params:
            if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                continue
            kind = "any" if p.name in LABELS.get(where, ()) else kind_of(p.name, str(p.annotation))
            others = {q.name: ctx.valid(q) for q in params
                      if q is not p and q.kind not in (q.VAR_POSITIONAL, q.VAR_KEYWORD)
                      and (q.default is inspect.Parameter.empty or TIME_NAMES.search(q.name))}

            def call(v: Any, others: Dict[str, Any] = others, p: inspect.Parameter = p) -> Any:
                kwargs = dict(others)
                kwargs[p.name] = v
                if p.kind == p.POSITIONAL_ONLY:
                    return fn(v, **{k: w for k, w in kwargs.items() if k != p.name})
                return fn(**kwargs)
            for v in bad_values(p, where):
                outcome(where, p, v, lambda v=v: call(v), kind in MUST_REFUSE)
            if kind == "bytes":
                base = ctx.valid(p) if p.default is inspect.Parameter.empty else b"\x01"
                if not isinstance(base, bytes) or not base:
                    base = b"\x01"
                results = []
                for form in (base, bytearray(base), memoryview(base + base)[::2]):
                    calls += 1
                    status, got = run_bounded(lambda form=form: call(form))
                    results.append((status, type(got).__name__ if status == "raised" else "ok"))
                    if status == "ok":
                        close_quietly(got)
                    elif status == "raised" and not isinstance(got, FapError):
                        note(where, p.name, form, "generic", f"{type(got).__name__}: {got}")
                if len(set(results)) > 1:
                    note(where, p.name, "bytes/bytearray/strided memoryview", "bytes_like",
                         f"outcomes differ: {results}")

    for modname, where, obj, cls in public_callables():
        modules.add(modname)
        if cls is None:
            sig = signature(obj)
            if sig and sig.parameters:
                walk_callable(where, obj, list(sig.parameters.values()))
            continue
        if is_record(cls):
            continue
        sig = signature(cls)
        params = list(sig.parameters.values()) if sig else []
        if params:
            walk_callable(where, cls, params)
        methods = [(m, f) for m, f in methods_of(cls)
                   if len((signature(f) or inspect.Signature()).parameters) > 1]
        if not methods:
            continue
        if where in NO_INSTANCE:
            continue
        make = facts.get(where)
        inst = None
        if make is not None:
            status, inst = run_bounded(make)
            if status != "ok":
                note(where, "-", "factory", "no_instance", f"factory failed: {inst!r}")
                continue
        else:
            status, inst = run_bounded(lambda: cls(**{q.name: ctx.valid(q) for q in params
                                                      if q.default is inspect.Parameter.empty
                                                      and q.kind not in (q.VAR_POSITIONAL,
                                                                         q.VAR_KEYWORD)}))
            if status != "ok":
                note(where, "-", "instance", "no_instance",
                     f"not built from valid values ({type(inst).__name__}: {inst}); "
                     "add a factory to walk_runner.factories")
                continue
        for m, _f in methods:
            bound = getattr(inst, m)
            sig = signature(bound)
            if sig and sig.parameters:
                walk_callable(f"{where}.{m}", bound, list(sig.parameters.values()))
        close_quietly(inst)
    return {"findings": findings, "calls": calls, "callables": callables,
            "modules": sorted(modules), "excluded": EXCLUDED, "walked": sorted(walked)}


def main() -> None:
    t0 = time.monotonic()
    report = walk()
    report["seconds"] = round(time.monotonic() - t0, 1)
    sys.stdout.write(json.dumps(report, default=str) + "\n")
    sys.stdout.flush()
    os._exit(0)          # threads a hang left behind must not keep the process


if __name__ == "__main__":
    main()
