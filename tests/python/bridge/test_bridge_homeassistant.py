"""Home Assistant MQTT discovery through ``fap bridge --config``, every payload checked
against Home Assistant's documented schema (MQTT sensor / binary_sensor, device,
availability), its templates rendered on what the bridge really published."""
from __future__ import annotations

import datetime
import json
import re
import signal
import subprocess
import sys

from bridge_helpers import WAIT, need

# Home Assistant's MQTT discovery schema (docs: integrations/sensor.mqtt, binary_sensor.mqtt, mqtt#discovery)
COMMON = {"availability", "availability_mode", "availability_template", "availability_topic", "device",
          "device_class", "enabled_by_default", "encoding", "entity_category", "entity_picture", "expire_after",
          "force_update", "icon", "json_attributes_template", "json_attributes_topic", "name", "object_id",
          "default_entity_id", "payload_available", "payload_not_available", "qos", "state_topic", "unique_id",
          "value_template", "origin", "platform"}
ALLOWED = {"sensor": COMMON | {"state_class", "unit_of_measurement", "suggested_display_precision",
                               "last_reset_value_template", "options"},
           "binary_sensor": COMMON | {"payload_on", "payload_off", "off_delay"}}
DEVICE_KEYS = {"configuration_url", "connections", "hw_version", "identifiers", "manufacturer", "model",
               "model_id", "name", "serial_number", "suggested_area", "sw_version", "via_device"}
AVAILABILITY_KEYS = {"payload_available", "payload_not_available", "topic", "value_template"}
ORIGIN_KEYS = {"name", "sw_version", "support_url"}
DEVICE_CLASSES = {"sensor": {"duration", "timestamp"}, "binary_sensor": {"connectivity"}}   # the ones HA has
DURATION_UNITS = {"d", "h", "min", "s", "ms"}
TOPIC = re.compile(r"^homeassistant/(sensor|binary_sensor)/[A-Za-z0-9_-]+/[A-Za-z0-9_-]+/config$")


def check_schema(topic: str, doc: dict) -> str:
    """The component; AssertionError naming what breaks Home Assistant's schema."""
    m = TOPIC.match(topic)
    assert m, topic
    comp = m.group(1)
    assert set(doc) <= ALLOWED[comp], (topic, set(doc) - ALLOWED[comp])
    assert isinstance(doc["state_topic"], str) and "+" not in doc["state_topic"] and "#" not in doc["state_topic"]
    assert isinstance(doc["unique_id"], str) and doc["unique_id"]      # required with a device
    assert isinstance(doc["name"], str) and doc["name"]
    dev = doc["device"]
    assert set(dev) <= DEVICE_KEYS and (dev.get("identifiers") or dev.get("connections")), dev
    assert all(isinstance(i, str) for i in dev["identifiers"])
    assert set(doc["origin"]) <= ORIGIN_KEYS and doc["origin"]["name"]
    for a in doc.get("availability", []):
        assert set(a) <= AVAILABILITY_KEYS and a["topic"], a
    if "device_class" in doc:
        assert doc["device_class"] in DEVICE_CLASSES[comp]
    if doc.get("device_class") == "duration":
        assert doc["unit_of_measurement"] in DURATION_UNITS
    assert doc.get("state_class", "measurement") in {"measurement", "total", "total_increasing"}
    assert doc.get("entity_category", "diagnostic") in {"config", "diagnostic"}
    assert doc.get("qos", 0) in (0, 1, 2)
    return comp


def render(template: str, payload: bytes) -> str:
    """A value_template as Home Assistant renders it (jinja2, value and value_json)."""
    import jinja2

    try:
        value_json = json.loads(payload)
    except ValueError:
        value_json = None
    return jinja2.Environment().from_string(template).render(value=payload.decode(), value_json=value_json)


def check_values(comp: str, doc: dict, payload: bytes) -> None:
    out = render(doc.get("value_template", "{{ value }}"), payload).strip()   # HA: no template = the payload
    if comp == "binary_sensor":
        assert out in (doc["payload_on"], doc["payload_off"]), (doc["name"], out)
    elif doc.get("device_class") == "timestamp":
        assert out == "None" or datetime.datetime.fromisoformat(out.replace("Z", "+00:00")).tzinfo
    elif doc.get("state_class") == "total_increasing":
        assert int(out) >= 0, (doc["name"], out)
    elif doc.get("state_class") == "measurement":
        assert out == "None" or float(out) >= 0, (doc["name"], out)
    else:
        assert out, (doc["name"], payload)


def _configs(obs):
    """topic -> payload of the discovery configurations seen last (an empty one clears)."""
    out = {}
    for m in obs.messages:
        if m.topic.startswith("homeassistant/") and m.topic.endswith("/config"):
            out[m.topic] = json.loads(m.payload) if m.payload else None
    return {t: d for t, d in out.items() if d is not None}


def test_discovery(broker, observer_factory, tmp_path):
    try:
        import jinja2
    except ImportError:
        jinja2 = None
    need("jinja2 (renders Home Assistant's templates)", jinja2 is not None)
    from fap_py.execasync import Slave
    from fap_py.vbus import VirtualBus

    conf = tmp_path / "bridge.toml"
    obs = observer_factory(broker.port, "#")

    def wait_configs(pred, what):
        with obs._cond:
            ok = obs._cond.wait_for(lambda: pred(_configs(obs)), WAIT)
        assert ok, f"{what}: {sorted(_configs(obs))}"
        return _configs(obs)

    def node_configs(cfgs, node):
        return {t: d for t, d in cfgs.items() if f"_ex_{node}" in t}

    def run():
        return subprocess.Popen([sys.executable, "-m", "fap_py", "bridge", "--config", str(conf)],
                                stderr=subprocess.PIPE, text=True, cwd=str(tmp_path))

    def stop(proc):
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT + 10)
        assert proc.returncode == 0, err

    with VirtualBus(3) as bus, Slave(bus.paths[1], node=5, handler=lambda r: b"five").start(), \
            Slave(bus.paths[2], node=6, handler=lambda r: b"six").start():
        conf.write_text(f'[bridge]\nhost = "ha-test"\nstate_dir = "st"\nstats_interval = 0.1\n'
                        f'[broker]\nurl = "mqtt://127.0.0.1:{broker.port}"\nreconnect_min = 0.05\n'
                        f'reconnect_max = 0.2\n'
                        f'[[bus]]\nname = "ex"\nport = "{bus.paths[0]}"\nprotocol = "execasync"\n'
                        f'nodes = [5]\npoll_data = "01"\npoll_interval = 0.05\nhomeassistant = true\n')
        proc = run()
        try:
            first = wait_configs(lambda c: len(node_configs(c, 5)) == 8 and len(c) == 9, "node 5 + bridge")
            obs.wait_for("fap/ex/5/rx", lambda d: d["data"] == b"five".hex())
            obs.wait_for("fap/ex/stats", lambda d: d["nodes"]["5"]["reply_ms"] is not None)
            obs.wait_raw("fap/bridge/ha-test/status", b"online")
            ids = [d["unique_id"] for d in first.values()]
            assert len(set(ids)) == len(ids)
            for topic, doc in first.items():
                comp = check_schema(topic, doc)
                for key in ("state_topic", "json_attributes_topic"):   # topics that exist
                    if key in doc:
                        assert any(m.topic == doc[key] for m in obs.messages), (topic, doc[key])
                for a in doc.get("availability", []):                  # the bridge's last-will topic
                    assert a["topic"] == "fap/bridge/ha-test/status"
                latest = [m.payload for m in obs.messages if m.topic == doc["state_topic"]][-1]
                check_values(comp, doc, latest)
            nodes5 = node_configs(first, 5)
            assert {d["device"]["identifiers"][0] for d in nodes5.values()} == {"fap_ha-test_ex_5"}
            # a node not in the configuration appears: its device is announced
            obs.publish("fap/ex/6/tx", {"id": "hello-6", "data": "00"})
            obs.wait_for("fap/ex/6/rx", lambda d: d.get("reply_to") == "hello-6")
            cfgs = wait_configs(lambda c: len(node_configs(c, 6)) == 8, "node 6 after it answered")
            for topic, doc in node_configs(cfgs, 6).items():
                check_schema(topic, doc)
            # Home Assistant restarted (its birth message): every configuration again
            for topic in cfgs:
                obs.c.publish(topic, b"", qos=1, retain=True).wait_for_publish(WAIT)
            wait_configs(lambda c: not c, "cleared")
            obs.c.publish("homeassistant/status", b"online", qos=1).wait_for_publish(WAIT)
            wait_configs(lambda c: c == cfgs, "after Home Assistant's birth message")
            # a reconnect to the broker publishes them again
            for topic in cfgs:
                obs.c.publish(topic, b"", qos=1, retain=True).wait_for_publish(WAIT)
            wait_configs(lambda c: not c, "cleared")
            broker.restart()
            wait_configs(lambda c: c == cfgs, "after a broker restart")
        finally:
            stop(proc)
        obs.wait_raw("fap/bridge/ha-test/status", b"offline")      # the entities' availability
        # a restarted bridge: the same unique ids and payloads for what the configuration names
        for topic in first:
            obs.c.publish(topic, b"", qos=1, retain=True).wait_for_publish(WAIT)
        wait_configs(lambda c: not node_configs(c, 5), "cleared")
        proc = run()
        try:
            again = wait_configs(lambda c: len(node_configs(c, 5)) == 8 and len(c) >= 9, "after restart")
            assert {t: again[t] for t in first} == first
        finally:
            stop(proc)
