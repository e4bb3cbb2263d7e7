"""bridge.toml checking and the command's exit codes (no broker needed)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fap_py._protocols import get as get_protocol
from fap_py.bridge.config import BridgeConfigError, from_dict, load, parse_url
from fap_py.errors import InvalidValueError
from fap_py.fap import RS485, RS485Mode

BROKER = {"url": "mqtt://127.0.0.1"}


def _bus(**kw):
    return dict({"name": "line1", "port": "/dev/ttyUSB0", "protocol": "fap", "slaves": [1, 2]}, **kw)


def test_full_example_parses(tmp_path):
    conf = tmp_path / "bridge.toml"
    conf.write_text("""
[bridge]
host = "plc-01"
topic_prefix = "site/a"
qos = 1
state_dir = "state"
queue_max = 5000

[broker]
url = "mqtts://user:p%40ss@broker.example:8884"
ca = "ca.crt"
cert = "client.crt"
key = "client.key"

[[bus]]
name = "line1"
port = "/dev/ttyUSB0"
protocol = "fap"
slaves = [1, 2, 3]
rs485 = "kernel"
rts_before = 0.5
rts_polarity = "low"

[[bus]]
name = "cell"
port = "/dev/ttyUSB1"
protocol = "fap"
role = "slave"
id = 4

[[bus]]
name = "valves"
port = "/dev/ttyUSB2"
protocol = "g485"
poll_interval = 0.5
rs485 = "soft"
rts_after = 2
echo_suppression = true
device = [{address = 1, registers = [[1, 7], [8, 4]]}, {address = 2}]

[[bus]]
name = "ex"
port = "/dev/ttyUSB3"
protocol = "execasync"
nodes = [5, 6]
poll_data = "0102"

[[bus]]
name = "mk"
port = "/dev/ttyUSB4"
protocol = "mikroc"
""")
    cfg = load(str(conf))
    assert (cfg.host, cfg.prefix, cfg.qos, cfg.queue_max) == ("plc-01", "site/a", 1, 5000)
    b = cfg.broker
    assert (b.host, b.port, b.tls, b.username, b.password) == ("broker.example", 8884, True, "user", "p@ss")
    assert b.ca == str(tmp_path / "ca.crt") and cfg.state_dir == str(tmp_path / "state")
    line1, cell, valves, ex, mk = cfg.buses
    assert line1.slaves == (1, 2, 3) and line1.rs485.mode == RS485Mode.KERNEL
    assert line1.rs485.delay_before_send_us == 500 and not line1.rs485.rts_active_high
    assert line1.timeout == 1.0 and ex.timeout == 0.1
    assert (cell.role, cell.id) == ("slave", 4)
    assert valves.devices[0].registers == ((1, 7), (8, 4)) and valves.devices[1].registers == ()
    # a g485 bus takes the same RS-485 keys as the others (all run on the C port layer)
    assert valves.rs485 == RS485(mode=RS485Mode.SOFT_RTS, rts_active_high=True, delay_before_send_us=0,
                                 delay_after_send_us=2000, echo_suppression=True)
    assert ex.rs485 == RS485(mode=RS485Mode.AUTO, rts_active_high=True, delay_before_send_us=0,
                             delay_after_send_us=0, echo_suppression=False)   # the documented defaults
    assert ex.nodes == (5, 6) and ex.poll_data == b"\x01\x02"
    assert ex.options.nodes == (5, 6) and line1.options.slaves == (1, 2, 3)   # the plug-ins' own keys
    # "execasync" is an accepted alias: the bus's protocol is the one name
    assert [b.protocol for b in cfg.buses] == ["fap", "fap", "g485", "exec", "mikroc"]
    assert mk.baud == get_protocol("mikroc").default_baud   # the default baud comes from the protocol table


@pytest.mark.parametrize("data, words", [
    ({"bus": [_bus()]}, "[broker]"),
    ({"broker": BROKER}, "[[bus]]"),
    ({"broker": {"url": "http://x"}, "bus": [_bus()]}, "mqtt://"),
    ({"broker": {"url": "mqtt://x", "ca": "c"}, "bus": [_bus()]}, "mqtts"),
    ({"broker": {"url": "mqtts://x", "cert": "c"}, "bus": [_bus()]}, "go together"),
    ({"broker": BROKER, "bus": [_bus(colour="red")]}, "colour"),
    ({"broker": BROKER, "bus": [_bus(protocol="modbus")]}, "protocol"),
    ({"broker": BROKER, "bus": [_bus(slaves=[0])]}, "slaves"),
    ({"broker": BROKER, "bus": [_bus(slaves=[1, 1])]}, "twice"),
    ({"broker": BROKER, "bus": [_bus(baud="fast")]}, "baud"),
    ({"broker": BROKER, "bus": [_bus(rs485="maybe")]}, "rs485"),
    ({"broker": BROKER, "bus": [_bus(rs485="gpio")]}, "gpio_chip"),
    ({"broker": BROKER, "bus": [_bus(rs485="gpio", gpio_chip="/dev/gpiochip0", gpio_line=-1)]}, "gpio_line"),
    ({"broker": BROKER, "bus": [_bus(rs485="soft", gpio_line=3)]}, "gpio"),
    ({"broker": BROKER, "bus": [_bus(name="a/b")]}, "name"),
    ({"broker": BROKER, "bus": [_bus(), _bus()]}, "differ"),
    ({"broker": BROKER, "bus": [_bus(name="bridge")]}, "bridge"),
    ({"broker": BROKER, "bus": [_bus(protocol="execasync", role="slave")]}, "slave"),
    ({"broker": BROKER, "bus": [_bus(protocol="exec", role="slave")]}, "a exec bus is master"),
    ({"broker": BROKER, "bus": [_bus(baud=12345)]}, "baud 12345 is not a rate"),
    ({"broker": BROKER, "bus": [_bus(slaves=[get_protocol("fap").node_max + 1])]}, r"slaves must be in 1..31"),
    ({"broker": BROKER, "bus": [_bus(protocol="exec", nodes=[get_protocol("exec").broadcast])]}, "nodes must be in"),
    ({"broker": BROKER, "bus": [_bus(protocol="g485", device=[{"address": get_protocol("g485").node_max + 1}])]},
     "address must be in"),
    ({"broker": BROKER, "bus": [_bus(protocol="g485", device=[{"address": 1, "registers": [[99, 5]]}])]},
     "count"),
    ({"broker": BROKER, "bus": [_bus(protocol="g485", device=[], rs485="maybe")]}, "rs485"),
    ({"broker": BROKER, "bus": [_bus(protocol="g485", device=[], rts_polarity="up")]}, "rts_polarity"),
    ({"broker": BROKER, "bridge": {"qos": 3}, "bus": [_bus()]}, "qos"),
    ({"broker": BROKER, "bridge": {"topic_prefix": "a/#"}, "bus": [_bus()]}, "wildcard"),
    ({"broker": BROKER, "bus": [_bus()], "extra": 1}, "extra"),
])
def test_bad_configs_name_the_key(data, words):
    with pytest.raises(BridgeConfigError, match=words.replace("[", r"\[").replace("]", r"\]")) as info:
        from_dict(data)
    assert isinstance(info.value, InvalidValueError)


def test_gpio_direction_mode():
    """rs485 = "gpio" takes the DE/RE line like the CLI's --rs485 gpio (issue 22)."""
    cfg = from_dict({"broker": BROKER, "bus": [_bus(rs485="gpio", gpio_chip="/dev/gpiochip0", gpio_line=17,
                                                    rts_polarity="low", rts_after=1)]})
    rs = cfg.buses[0].rs485
    assert rs.mode == RS485Mode.GPIO and rs.gpio_chip == "/dev/gpiochip0" and rs.gpio_line == 17
    assert not rs.rts_active_high and rs.delay_after_send_us == 1000


def test_shipped_example_parses():
    example = Path(__file__).resolve().parents[3] / "examples" / "bridge" / "bridge.toml"
    cfg = load(str(example))
    assert [b.protocol for b in cfg.buses] == ["fap", "fap", "g485", "exec", "mikroc"]
    valves = cfg.buses[2]
    assert valves.rs485.mode == RS485Mode.SOFT_RTS and valves.rs485.echo_suppression
    assert valves.rs485.delay_after_send_us == 1000


def test_url_defaults():
    assert parse_url("mqtt://h") == ("h", 1883, False, None, None)
    assert parse_url("mqtts://h") == ("h", 8883, True, None, None)


def _fap(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "fap_py", *args], capture_output=True, text=True,
                          timeout=60, cwd=cwd)


def test_cli_exit_codes(tmp_path):
    res = _fap("bridge", "--config", str(tmp_path / "missing.toml"), cwd=tmp_path)
    assert res.returncode == 3 and res.stderr.startswith("fap: error: ") and len(res.stderr.splitlines()) == 1
    bad = tmp_path / "bad.toml"
    bad.write_text("[broker]\nurl = 'mqtt://x'\n[[bus]]\nname = 'l'\nport = 'p'\nprotocol = 'nope'\n")
    res = _fap("bridge", "--config", str(bad), cwd=tmp_path)
    assert res.returncode == 2 and "protocol" in res.stderr and len(res.stderr.splitlines()) == 1
    good = tmp_path / "good.toml"
    good.write_text("[broker]\nurl = 'mqtt://x'\n[[bus]]\nname = 'l'\nport = '/dev/null'\n"
                    "protocol = 'fap'\nslaves = [1]\n")
    res = _fap("bridge", "--config", str(good), "--check", cwd=tmp_path)
    assert res.returncode == 0 and "ok: 1 bus" in res.stdout
    missing = tmp_path / "missing-port.toml"    # --check names a port that is not there
    missing.write_text(good.read_text().replace("/dev/null", "p"))
    res = _fap("bridge", "--config", str(missing), "--check", cwd=tmp_path)
    assert res.returncode == 3 and res.stderr == "fap: error: bus 'l'.port: p: No such file or directory\n"
    res = _fap("bridge", "--help", cwd=tmp_path)
    assert res.returncode == 0 and "example:" in res.stdout


BLOCK_PAHO = "import sys; sys.modules['paho'] = None; sys.modules['paho.mqtt'] = None; " \
             "sys.modules['paho.mqtt.client'] = None; from fap_py.cli import main; sys.exit(main(sys.argv[1:]))"


def test_without_paho(tmp_path):
    res = subprocess.run([sys.executable, "-c", BLOCK_PAHO, "--help"], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)
    assert res.returncode == 0 and "bridge" in res.stdout
    good = tmp_path / "good.toml"
    good.write_text("[broker]\nurl = 'mqtt://x'\n[[bus]]\nname = 'l'\nport = 'p'\nprotocol = 'fap'\nslaves = [1]\n")
    res = subprocess.run([sys.executable, "-c", BLOCK_PAHO, "bridge", "--config", str(good)],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip() == "fap: error: fap bridge needs paho-mqtt 2.x: pip install 'fap_py[bridge]'"


# -- hostile configurations (issue 26): exit 2 and one line naming the field, never "internal error"

BASE = "[broker]\nurl = 'mqtt://x'\n"
GOOD_BUS = "[[bus]]\nname = 'l'\nport = '/dev/null'\nprotocol = 'fap'\nslaves = [1]\n"


@pytest.mark.parametrize("text, words", [
    (b"\xff\xfe" + BASE.encode() + GOOD_BUS.encode(), "not UTF-8"),
    (b"bus = [1]\n" + BASE.encode(), "bus[0] must be a table"),
    (b'bus = ["ab"]\n' + BASE.encode(), "bus[0] must be a table"),
    (b'bus = [[["name", "x"]]]\n' + BASE.encode(), "bus[0] must be a table"),
    (b'[broker]\nurl = "mqtt://[::1"\n' + GOOD_BUS.encode(), "broker.url"),
    (b"x = " + b"[" * 3000 + b"]" * 3000 + b"\n" + BASE.encode(), "nested too deeply"),
    (BASE.encode() + b"[metrics]\nlisten = 'nowhere'\n" + GOOD_BUS.encode(), "metrics.listen"),
    (BASE.encode() + GOOD_BUS.encode() + b"timeout = 1" + b"0" * 400 + b"\n", ".timeout"),
    (BASE.encode() + GOOD_BUS.encode() + b"timeout = 1" + b"0" * 5000 + b"\n", "4300 digits"),
    (BASE.replace("[broker]", "[broker]\nprotocol = '4'").encode() + GOOD_BUS.encode(), "broker.protocol"),
])
def test_bad_config_files_exit_2_naming_the_field(tmp_path, text, words):
    conf = tmp_path / "bridge.toml"
    conf.write_bytes(text)
    res = _fap("bridge", "--config", str(conf), "--check", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert res.stderr.startswith("fap: error: ") and words in res.stderr and len(res.stderr.splitlines()) == 1


def test_load_takes_paths_only(tmp_path):
    from fap_py.bridge.config import BridgeConfigTypeError

    for bad in (5, None, b"bridge.toml", 1.5):
        with pytest.raises(BridgeConfigTypeError) as info:
            load(bad)
        assert isinstance(info.value, TypeError) and isinstance(info.value, BridgeConfigError)
    conf = tmp_path / "bridge.toml"
    conf.write_text(BASE + GOOD_BUS)
    assert load(conf).buses[0].name == "l"          # os.PathLike is a path


@pytest.mark.parametrize("target", ["/dev/zero", "dir", "fifo", "big"])
def test_named_files_are_bounded(tmp_path, target):
    from fap_py.bridge.files import BridgeFileError

    (tmp_path / "dir").mkdir()
    os.mkfifo(tmp_path / "fifo")       # nobody writes it: opening must not wait
    (tmp_path / "big").write_bytes(b"x" * (2 << 20))
    conf = tmp_path / "bridge.toml"
    conf.write_text(BASE.replace("[broker]", f"[broker]\npassword_file = '{target}'") + GOOD_BUS)
    with pytest.raises(BridgeFileError, match="broker.password_file"):
        load(str(conf))
    with pytest.raises(BridgeFileError, match="configuration"):
        load(str(tmp_path / target))


KEYS = ["broker", "bridge", "bus", "metrics", "url", "name", "port", "protocol", "slaves", "role", "id",
        "device", "address", "registers", "baud", "timeout", "qos", "host", "topic_prefix", "state_dir",
        "password_file", "ca", "cert", "key", "listen", "nodes", "poll_data", "rs485", "rts_before",
        "reopen_interval", "session_expiry", "keepalive", "reconnect_min", "reconnect_max", "queue_max"]


def _values():
    from hypothesis import strategies as st

    scalars = st.one_of(st.booleans(), st.integers(), st.integers(-2, 300), st.sampled_from([10**400, -10**400, 10**1000]),
                        st.floats(allow_nan=True, allow_infinity=True),
                        st.sampled_from(["fap", "g485", "exec", "execasync", "mikroc", "master", "slave", "mqtt://h",
                                         "mqtts://h:1", "mqtt://[::1", "/dev/null", "/dev/zero", "5", "3.1.1",
                                         "127.0.0.1:0", "auto", "zz", ""]),
                        st.text(max_size=8))
    return st.recursive(scalars, lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(st.one_of(st.sampled_from(KEYS), st.text(max_size=4)), inner, max_size=6)),
        max_leaves=30)


def test_random_configs_never_end_in_an_internal_error(tmp_path):
    """A valid configuration with random keys set to random values anywhere (from_dict), and
    its file with random bytes written over it (load): a config or file error, nothing else."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from fap_py.bridge.files import BridgeFileError

    def base():
        return {"broker": {"url": "mqtt://x"}, "bridge": {}, "metrics": {},
                "bus": [{"name": "l", "port": "/dev/null", "protocol": "fap", "slaves": [1]},
                        {"name": "g", "port": "/dev/null", "protocol": "g485",
                         "device": [{"address": 1, "registers": [[1, 2]]}]}]}

    places = st.sampled_from(["top", "broker", "bridge", "metrics", "bus0", "bus1", "device"])

    @settings(max_examples=250, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    @given(st.lists(st.tuples(places, st.sampled_from(KEYS), _values()), min_size=1, max_size=4))
    def tables(edits):
        data = base()
        tables = {"top": data, "broker": data["broker"], "bridge": data["bridge"], "metrics": data["metrics"],
                  "bus0": data["bus"][0], "bus1": data["bus"][1], "device": data["bus"][1]["device"][0]}
        for place, key, value in edits:    # the tables of the base, whatever an edit replaced
            tables[place][key] = value
        try:
            from_dict(data, str(tmp_path))
        except (BridgeConfigError, BridgeFileError):
            pass

    good = (BASE + GOOD_BUS).encode()

    @settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    @given(st.lists(st.tuples(st.integers(0, len(good)), st.binary(max_size=6)), max_size=4))
    def files(edits):
        text = good
        for at, insert in edits:
            text = text[:at] + insert + text[at + len(insert):]
        conf = tmp_path / "fuzz.toml"
        conf.write_bytes(text)
        try:
            load(str(conf))
        except (BridgeConfigError, BridgeFileError):
            pass

    tables()
    files()


@pytest.mark.parametrize("table, module, hint", [
    ("[metrics]\nlisten = '127.0.0.1:0'\n", "prometheus_client", "[metrics] needs prometheus_client"),
    ("[sparkplug]\ngroup_id = 'g'\n", "google.protobuf", "[sparkplug] needs protobuf"),
])
def test_optional_parts_without_their_dependency(tmp_path, table, module, hint):
    block = f"import sys; sys.modules[{module!r}] = None"
    conf = tmp_path / "bridge.toml"
    conf.write_text(f"[bridge]\nstate_dir = 'st'\n{table}[broker]\nurl = 'mqtt://127.0.0.1:1'\n"
                    "[[bus]]\nname = 'l'\nport = '/dev/null'\nprotocol = 'fap'\nslaves = [1]\n")
    res = subprocess.run([sys.executable, "-c", block + "; from fap_py.cli import main; sys.exit(main(sys.argv[1:]))",
                          "bridge", "--config", str(conf)], capture_output=True, text=True, timeout=60,
                         cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines()[-1] == f"fap: error: {hint}: pip install 'fap_py[bridge]'"


def test_protocol_keys_live_in_the_plugins():
    """Each protocol's own keys are its plug-in's (BusConfig.options); node ranges and the
    FAP receive-queue depth are checked there; the old names still resolve, with a warning."""

    from fap_py.bridge import buses, config
    from fap_py.bridge.protocols import fap as fap_plugin

    ex_bus = {"name": "ex", "port": "/dev/ttyUSB1", "protocol": "execasync", "nodes": [1]}
    cfg = from_dict({"broker": BROKER, "bus": [_bus(rx_queue=64), ex_bus]})
    line1, ex = cfg.buses
    assert line1.options == fap_plugin.Options(slaves=(1, 2), rx_queue=64) and ex.protocol == "exec"
    assert from_dict({"broker": BROKER, "bus": [_bus()]}).buses[0].options.rx_queue == fap_plugin.RX_QUEUE
    with pytest.raises(BridgeConfigError, match="rx_queue"):
        from_dict({"broker": BROKER, "bus": [_bus(rx_queue=0)]})
    with pytest.raises(BridgeConfigError, match="unknown key.*slaves"):   # a FAP key on an exec bus
        from_dict({"broker": BROKER, "bus": [_bus(protocol="exec")]})
    # the names that forwarded to the plug-ins are gone (CHANGELOG.md)
    for mod, name in ((buses, "ExecAsyncAdapter"), (config, "G485Device"), (config, "PROTOCOLS"),
                      (buses, "ModbusAdapter")):
        with pytest.raises(AttributeError):
            getattr(mod, name)
    assert get_protocol("exec").plugin("bridge").Adapter is not None
