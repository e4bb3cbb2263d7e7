"""The bridge's outputs behind one interface (issue 31, "The bridge's north side has no
seam"): ``fap_py/bridge/bridge.py`` names no integration, and a fourth output out of
tree (toy_output.py) plugs in by name with no edit to fap_py, fed through the one
interface by a real bridge on a real mosquitto."""
from __future__ import annotations

import io
import os
import re
import socket
import tokenize

import pytest
from bridge_helpers import WAIT, bridge_config

import fap_py.bridge

BRIDGE_PY = os.path.join(os.path.dirname(fap_py.bridge.__file__), "bridge.py")
INTEGRATION = re.compile(r"home.?assistant|sparkplug|metrics|prometheus|discovery", re.IGNORECASE)


@pytest.fixture
def fap_bus():
    from fap_py.fap import Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(3) as bus:
        with Slave(bus.paths[1], id=1) as s1:
            yield bus, s1


@pytest.fixture
def toy(monkeypatch):
    import toy_output

    monkeypatch.setenv("FAP_BRIDGE_OUTPUTS", "toy_output:ToyOutput")
    toy_output.ToyOutput.made.clear()
    monkeypatch.setattr(toy_output.ToyOutput, "fail_start", False)
    return toy_output


def _buses(bus):
    return [{"name": "line1", "port": bus.paths[0], "protocol": "fap", "role": "master", "slaves": [1],
             "id_cycle": 0.1}]


def test_the_orchestrator_names_no_integration():
    """Every token of bridge.py (names, strings, comments): no integration is named."""
    with open(BRIDGE_PY, encoding="utf-8") as f:
        src = f.read()
    found = [(t.start[0], t.string) for t in tokenize.generate_tokens(io.StringIO(src).readline)
             if INTEGRATION.search(t.string)]
    assert not found, found
    from fap_py.bridge import outputs

    assert outputs.BUILTIN == ("metrics", "homeassistant", "sparkplug")
    for name in outputs.BUILTIN:   # one file each, found by name
        assert callable(outputs.factory(name))


def test_unknown_outputs_and_bad_references_are_clear_errors(monkeypatch, tmp_path):
    from fap_py.bridge import outputs
    from fap_py.errors import FapError

    with pytest.raises(outputs.UnknownOutputError, match="no bridge output 'nope'"):
        outputs.factory("nope")
    monkeypatch.setenv("FAP_BRIDGE_OUTPUTS", "no_such_module_here:create")
    with pytest.raises(outputs.UnknownOutputError, match="FAP_BRIDGE_OUTPUTS: cannot load"):
        outputs.names()
    monkeypatch.delenv("FAP_BRIDGE_OUTPUTS")
    with pytest.raises(FapError, match="already registered"):
        outputs.register("sparkplug", lambda config: None)
    calls = []
    outputs.register("counted", lambda config: calls.append(config))
    try:
        assert "counted" in outputs.names()
        assert outputs.build(bridge_config(1, str(tmp_path), [{"name": "b", "port": "/dev/ttyUSB9", "protocol": "fap", "slaves": [1]}])) == [] and len(calls) == 1
    finally:
        outputs.unregister("counted")
    assert "counted" not in outputs.names()


def test_a_fourth_output_plugs_in_by_name_and_is_fed(broker, observer_factory, fap_bus, tmp_path, toy):
    from fap_py.bridge import Bridge
    from fap_py.bridge.outputs import RX, SEEN, STATE, BridgeView, NodeView

    bus, s1 = fap_bus
    obs = observer_factory(broker.port, "fap/#")
    cfg = bridge_config(broker.port, str(tmp_path / "state"), _buses(bus))
    bridge = Bridge(cfg)
    (out,) = toy.ToyOutput.made
    assert bridge.output("toy") is out and list(bridge.outputs) == ["toy"]   # nothing else configured
    with bridge:
        assert bridge.wait_connected(WAIT)
        assert out.wait(lambda c: c[0] == "connect" and c[1] is True, WAIT)
        start = [c for c in out.calls if c[0] == "start"]
        assert len(start) == 1 and isinstance(start[0][1], BridgeView)
        ctx = start[0][1]
        # read-only: the view and its mapping of buses
        with pytest.raises(AttributeError):
            ctx.config = None
        with pytest.raises(TypeError):
            ctx.buses["x"] = None
        assert set(ctx.buses) == {"line1"} and ctx.link is bridge.link and ctx.output("toy") is out
        # a node event: a message received, after the node's state (seen, then active)
        s1.send(b"hello")
        obs.wait_for("fap/line1/1/rx")
        assert out.wait(lambda c: c[0] == "event" and c[1] == RX, WAIT)
        events = [c[1:] for c in out.calls if c[0] == "event"]
        kinds = [e[0] for e in events]
        active = [i for i, e in enumerate(events) if e[0] == STATE and e[1:4] == ("line1", 1, True)]
        assert kinds.index(SEEN) < active[0] < kinds.index(RX), events
        rx = [e for e in events if e[0] == RX][0]
        assert rx[1:3] == ("line1", 1) and rx[4]["data"] == "68656c6c6f" and rx[5] == 1   # view.rx counted
        view = rx[6]
        assert isinstance(view, NodeView) and (view.bus, view.node) == ("line1", 1)
        with pytest.raises(AttributeError):
            view.rx = 0
        # the topics it subscribes to come to on_message
        obs.c.publish(toy.TOPIC, b"ping", qos=1).wait_for_publish(WAIT)
        assert out.wait(lambda c: c == ("message", toy.TOPIC, b"ping"), WAIT)
        assert out.wait(lambda c: c[0] == "tick", WAIT)   # every stats_interval while connected
        assert not any(c[0] == "stop" for c in out.calls)
    assert out.calls[-1] == ("stop",)
    assert sum(1 for c in out.calls if c[0] == "stop") == 1


def test_an_output_that_cannot_start_stops_the_start(broker, fap_bus, tmp_path, toy):
    """start() raising: the error reaches the caller, the outputs started before it (the
    metrics endpoint) are stopped and no bus is opened."""
    pytest.importorskip("prometheus_client")
    from fap_py.bridge import Bridge
    from fap_py.bridge.config import from_dict

    bus, s1 = fap_bus
    toy.ToyOutput.fail_start = True
    cfg = from_dict({"broker": {"url": f"mqtt://127.0.0.1:{broker.port}"},
                     "bridge": {"host": "test", "state_dir": str(tmp_path / "state")},
                     "metrics": {"listen": "127.0.0.1:0"}, "bus": _buses(bus)})
    bridge = Bridge(cfg)
    assert list(bridge.outputs) == ["metrics", "toy"]
    with pytest.raises(OSError, match="toy output: cannot start"):
        bridge.start()
    metrics = bridge.output("metrics")
    with pytest.raises(ConnectionRefusedError):   # started first, closed by the failed start
        socket.create_connection(("127.0.0.1", metrics.port), timeout=WAIT).close()
    assert all(not b.running for b in bridge.buses.values())
    assert not [c for c in toy.ToyOutput.made[0].calls if c[0] == "start"]


def test_output_base_defaults_take_what_the_bridge_hands_and_the_view_checks_its_calls(
        broker, observer_factory, fap_bus, tmp_path, caplog):
    """An output that overrides no hook: OutputBase's defaults check their arguments, and
    a real bridge's (a BridgeView, its MqttLink, NodeView + NodeEvent, a topic and bytes)
    pass them, nothing logged. Its view's calls refuse bad values with the package's errors
    (an unknown bus named with the known ones, a wildcard topic, a str payload) and publish
    good ones."""
    import logging
    import threading

    from fap_py.bridge import Bridge, outputs
    from fap_py.errors import InvalidTypeError, InvalidValueError

    class Plain(outputs.OutputBase):
        """Each hook runs OutputBase's default (its checks), then notes the call."""
        name = "plain"

        def __init__(self):
            self.seen, self.cond = [], threading.Condition()

        def _note(self, what):
            with self.cond:
                self.seen.append(what)
                self.cond.notify_all()

        def wait(self, what):
            with self.cond:
                return self.cond.wait_for(lambda: what in self.seen, WAIT)

        def subscriptions(self):
            return ("plain/cmd",)

        def start(self, ctx):
            super().start(ctx)
            self._note("start")

        def on_connect(self, link):
            super().on_connect(link)
            self._note("connect")

        def on_node_event(self, view, event):
            super().on_node_event(view, event)
            self._note(event.kind)

        def on_message(self, topic, payload):
            super().on_message(topic, payload)
            self._note(("message", topic, payload))

    made = []
    outputs.register("plain", lambda config: made.append(Plain()) or made[-1])
    try:
        bus, s1 = fap_bus
        obs = observer_factory(broker.port, "fap/#")
        bridge = Bridge(bridge_config(broker.port, str(tmp_path / "state"), _buses(bus)))
        (out,) = made
        caplog.set_level(logging.ERROR, logger="fap_py.bridge")
        with bridge:
            assert bridge.wait_connected(WAIT)
            ctx = out.ctx
            assert isinstance(ctx, outputs.BridgeView)
            s1.send(b"hello")                              # SEEN, STATE, RX: on_node_event
            obs.wait_for("fap/line1/1/rx")
            assert out.wait("connect") and out.wait(outputs.RX)
            obs.c.publish("plain/cmd", b"ping", qos=1).wait_for_publish(WAIT)   # on_message
            assert out.wait(("message", "plain/cmd", b"ping"))
            ctx.publish_now("fap/plain/hello", b"hi", False)
            obs.wait_raw("fap/plain/hello", b"hi")
            assert ctx.node("line1", 1).rx >= 1 and ctx.output("plain") is out
            with pytest.raises(InvalidValueError, match=r"no bus 'line9'.*line1"):
                ctx.node("line9", 1)
            with pytest.raises(InvalidValueError, match="0..255"):
                ctx.node("line1", 256)
            with pytest.raises(InvalidValueError, match="wildcard"):
                ctx.publish_now("fap/+/x", b"x")
            with pytest.raises(InvalidTypeError, match="payload must be bytes-like, not str"):
                ctx.publish_now("fap/plain/x", "x")
            with pytest.raises(InvalidTypeError, match="retain must be a bool"):
                ctx.publish_now("fap/plain/x", b"x", 1)
            with pytest.raises(InvalidTypeError, match="ctx must be a BridgeView"):
                out.start(bridge)
        hooks = [r.getMessage() for r in caplog.records if r.getMessage().startswith("output plain")]
        assert not hooks, hooks
    finally:
        outputs.unregister("plain")
