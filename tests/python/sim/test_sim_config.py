"""``fap sim --check`` and ``--schema``: one schema, line-numbered errors, hostile configs."""
from __future__ import annotations

import json
import os
import sys

import pytest

from fap_py.errors import InvalidValueError
from fap_py.sim import SimConfigError, load, loads
from fap_py.sim._schema import schema, validate

from .conftest import EXAMPLES, run

GOOD = """\
[sim]
seed = 1

[[bus]]
name = "a"
protocol = "exec"

[[bus.node]]
address = 5

[[bus.node]]
range = [10, 20]
answer = "value"
value = { kind = "counter" }

[[bus]]
name = "b"
protocol = "g485"

[[bus.node]]
address = 9
registers = [{ register = 10, type = "u16" }]
"""


def _write(tmp_path, name: str, text: str) -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def check_err(path: str) -> str:
    r = run("sim", "--check", path)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr      # one clear line, no traceback
    return lines[0]


def test_good_config_checks(tmp_path):
    r = run("sim", "--check", _write(tmp_path, "good.toml", GOOD))
    assert r.returncode == 0, r.stderr
    assert "ok (2 buses" in r.stdout


@pytest.mark.parametrize("edit,line,words", [
    # an unknown key in the second node: line 13
    (lambda t: t.replace('answer = "value"', 'answr = "value"'), 13, "unknown key 'answr'"),
    # a wrong type: line 9
    (lambda t: t.replace("address = 5", 'address = "five"'), 9, "must be an integer"),
    # an address outside the protocol's range (exec: 1..254)
    (lambda t: t.replace("address = 5", "address = 255"), 9, "not a node address of exec (1..254)"),
    # the same address twice: node[1]'s range holds 10..20
    (lambda t: t.replace("address = 5", "address = 12"), 11, "address 12 is already node[0]'s"),
    # G485 register type past register 100, inside an inline table: its key's line
    (lambda t: t.replace("register = 10,", "register = 100,"), 22, "ends past register 100"),
    # a TOML syntax error: tomllib's own line
    (lambda t: t.replace('name = "b"', 'name = "b'), 17, "TOML"),
    # an unknown protocol
    (lambda t: t.replace('protocol = "g485"', 'protocol = "modbus"'), 18, "'modbus' is not one of"),
])
def test_check_errors_name_file_and_line(tmp_path, edit, line, words):
    path = _write(tmp_path, "site.toml", edit(GOOD))
    msg = check_err(path)
    assert msg.startswith(f"fap: error: {path}:{line}: "), msg
    assert words in msg


def test_json_errors_have_lines(tmp_path):
    cfg = {"bus": [{"protocol": "mikroc", "node": [{"address": 7}, {"address": 50}]}]}
    text = json.dumps(cfg, indent=2)
    path = _write(tmp_path, "site.json", text)
    msg = check_err(path)
    want = [i for i, ln in enumerate(text.splitlines(), 1) if '"address": 50' in ln][0]
    assert msg.startswith(f"fap: error: {path}:{want}: bus[0].node[1].address: address 50"), msg
    bad = _write(tmp_path, "broken.json", '{\n "bus": [\n  {"protocol": "exec",,}\n ]\n}\n')
    assert check_err(bad).startswith(f"fap: error: {bad}:3: JSON:")


def test_hostile_configs(tmp_path):
    # a huge table: refused by size, one line
    rows = ",".join('{ request = "01", reply = "02" }' for _ in range(2000))
    huge = GOOD.replace('answer = "value"', f'answer = "table"\ntable = [{rows}]')
    msg = check_err(_write(tmp_path, "huge.toml", huge))
    assert "2000 items, at most 1024" in msg and ":14:" in msg


def test_hostile_files(tmp_path):
    # a file far too large
    big = tmp_path / "big.toml"
    big.write_text("# x\n" * 400_000)
    assert "a config is at most" in check_err(str(big))
    # not UTF-8
    assert "not UTF-8" in check_err(str(_bytes(tmp_path)))


def test_hostile_documents(tmp_path):
    # a top level that is not a table
    assert "top level" in check_err(_write(tmp_path, "list.json", "[1, 2]"))
    # NaN is not JSON
    assert "JSON" in check_err(_write(tmp_path, "nan.json", '{"bus": NaN}'))
    # deep nesting
    assert "fap: error:" in check_err(_write(tmp_path, "deep.json", "[" * 100000 + "]" * 100000))


def _bytes(tmp_path):
    p = tmp_path / "bin.toml"
    p.write_bytes(b"a = '\xff\xfe'\n")
    return p


def test_hook_module_that_raises(tmp_path, monkeypatch):
    (tmp_path / "evil_hook.py").write_text("raise RuntimeError('boom at import')\n")
    (tmp_path / "good_hook.py").write_text("def value(t, state):\n    return 42\n")
    monkeypatch.setenv("PYTHONPATH", str(tmp_path) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    text = GOOD.replace('value = { kind = "counter" }', 'value = { kind = "hook", function = "evil_hook:value" }')
    msg = check_err(_write(tmp_path, "hook.toml", text))
    assert ":14: bus[0].node[1].value.function:" in msg and "RuntimeError: boom at import" in msg
    text = GOOD.replace('value = { kind = "counter" }', 'value = { kind = "hook", function = "good_hook:nothere" }')
    assert "has no function 'nothere'" in check_err(_write(tmp_path, "hook2.toml", text))
    text = GOOD.replace('value = { kind = "counter" }', 'value = { kind = "hook", function = "good_hook:value" }')
    assert run("sim", "--check", _write(tmp_path, "hook3.toml", text)).returncode == 0


def test_yaml(tmp_path):
    pytest.importorskip("yaml")
    path = _write(tmp_path, "site.yaml", "bus:\n  - protocol: exec\n    node:\n      - address: 5\n      - adress: 6\n")
    assert check_err(path).startswith(f"fap: error: {path}:5: ")
    rec = _write(tmp_path, "rec.yaml", "a: &x [*x]\nbus: []\n")
    assert "aliases" in check_err(rec)


def test_yaml_without_pyyaml_is_one_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "yaml", None)     # PyYAML hidden: import yaml fails
    with pytest.raises(SimConfigError) as e:
        loads("bus: []\n", "site.yaml", "yaml")
    assert "needs PyYAML" in str(e.value)


def test_errors_are_the_package_hierarchy():
    with pytest.raises(SimConfigError) as e:
        loads('bus = 3', "x.toml")
    assert isinstance(e.value, InvalidValueError) and e.value.line == 1


def test_schema_is_json_schema():
    r = run("sim", "--schema")
    assert r.returncode == 0
    s = json.loads(r.stdout)
    assert s == json.loads(json.dumps(schema()))
    assert s["$schema"].startswith("https://json-schema.org/")
    for name in ("fap", "exec", "mikroc", "g485"):
        assert s["$defs"][f"bus_{name}"]["properties"]["protocol"] == {"const": name}
    examples = [os.path.join(EXAMPLES, f) for f in sorted(os.listdir(EXAMPLES))]
    try:
        import jsonschema
    except ImportError:
        jsonschema = None
    for path in examples:
        cfg = load(path)
        assert validate(cfg, s) == []
        if jsonschema is not None:
            jsonschema.Draft202012Validator.check_schema(s)
            jsonschema.validate(cfg, s)
    # our validator refuses what the schema refuses
    assert validate({"bus": [{"protocol": "exec", "node": [{"address": "x"}]}]}, s)


def test_docs_reference_is_the_schema():
    from fap_py.sim._schema import reference_markdown

    from .conftest import ROOT
    text = open(os.path.join(ROOT, "docs", "sim.md"), encoding="utf-8").read()
    begin, end = "<!-- schema-reference:begin -->\n", "<!-- schema-reference:end -->"
    assert text[text.index(begin) + len(begin):text.index(end)] == reference_markdown(), \
        "regenerate docs/sim.md's schema reference from fap_py.sim._schema.reference_markdown()"


def test_python_api_refuses_bad_arguments_with_package_errors(tmp_path) -> None:
    """The sim's public Python API (fap_py.sim.__all__) checks its arguments: a dict built
    in Python gets the checks of loads (it used to reach the bus code as a KeyError or
    TypeError), and bad ports, bauds, clocks, texts and times are package errors."""
    from fap_py.errors import FapError, InvalidTypeError
    from fap_py.sim import FastClock, FaultError, ManualClock, Sim

    good = '[[bus]]\nprotocol = "exec"\n[[bus.node]]\naddress = 1\n'
    with pytest.raises(InvalidTypeError, match="config must be a dict"):
        Sim([])
    with pytest.raises(SimConfigError, match="bus"):
        Sim({})
    with pytest.raises(SimConfigError, match="protocol"):
        Sim({"bus": [{"protocol": "nope", "node": [{"address": 1}]}]})
    with pytest.raises(InvalidTypeError):
        Sim(loads(good), clock="now")
    with pytest.raises(InvalidValueError):
        Sim(loads(good), baud=-1)
    with pytest.raises(InvalidValueError):
        Sim(loads(good), port="")
    with pytest.raises(InvalidTypeError, match="config text must be a str"):
        loads(b"x")
    with pytest.raises(InvalidValueError, match="config format must be one of"):
        loads(good, "<c>", "ini")
    with pytest.raises(InvalidTypeError):
        load(3)          # an fd: it used to be read (and closed) as the config
    for bad in (float("nan"), -1, "1"):
        with pytest.raises(FapError):
            ManualClock().advance(bad)
        with pytest.raises(FapError):
            FastClock(bad)
    with Sim(loads(good)) as sim:
        f = sim.add_fault("no_reply", node=1)
        with pytest.raises(FaultError, match="a fault id is an int"):
            sim.remove_fault(True)
        with pytest.raises(InvalidTypeError):
            sim.add_fault(5)
        with pytest.raises(InvalidTypeError):
            sim.wait_for(5)
        with pytest.raises(InvalidValueError):
            sim.wait_for(lambda s: True, timeout=float("nan"))
        assert [g["id"] for g in sim.remove_fault(f["id"])] == [f["id"]]
        assert sim.faults_list() == []
