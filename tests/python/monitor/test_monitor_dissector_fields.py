"""The shipped Lua dissector's field table against the monitor plug-ins: every field a
plug-in lists (its JSON schema) is a Wireshark field ``<dissector>.<field>``, and the
dissector's protocol ids are the protocol table's pcap ids. A field added to a plug-in
without the dissector (or the other way round) fails here, without tshark."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

import fap_py.monitor
from fap_py import _protocols
from fap_py.monitor.decoders import dissector, monitor_protocols, plugin

LUA = Path(fap_py.monitor.__file__).parent / "dissectors" / "fap_monitor.lua"


def lua_fields() -> set:
    return set(re.findall(r'ProtoField\.\w+\("([\w.]+)"', LUA.read_text(encoding="utf-8")))


def lua_protocol_ids() -> dict:
    text = LUA.read_text(encoding="utf-8")
    table = re.search(r"PROTOCOL_NAMES\s*=\s*\{([^}]*)\}", text)
    assert table, "fap_monitor.lua lost its PROTOCOL_NAMES table"
    return {int(i): name for i, name in re.findall(r'\[(\d+)\]\s*=\s*"(\w+)"', table.group(1))}


@pytest.mark.parametrize("protocol", monitor_protocols())
def test_every_plugin_field_is_a_dissector_field(protocol):
    have = lua_fields()
    prefix = dissector(protocol)
    missing = [f for f in plugin(protocol).FIELDS if f"{prefix}.{f}" not in have]
    assert not missing, f"{LUA.name} lacks {', '.join(f'{prefix}.{f}' for f in missing)}"
    assert re.search(rf'Proto\("{prefix}",', LUA.read_text(encoding="utf-8"))


def test_dissector_protocol_ids_are_the_tables():
    want = {p.pcap_id: p.name for p in _protocols.PROTOCOLS if p.has_plugin("monitor")}
    assert lua_protocol_ids() == want


def test_dissector_fields_belong_to_a_plugin():
    """Every field of a protocol's dissector is a plug-in field or a wire-only one
    (size, CRC, check, length, DATALEN: bytes the monitor's JSON does not repeat)."""
    wire_only = {"size", "crc", "check", "length", "datalen"}
    prefixes = {dissector(p): p for p in monitor_protocols()}
    for name in lua_fields():
        prefix, _, field = name.partition(".")
        if prefix in prefixes:
            assert field in plugin(prefixes[prefix]).FIELDS or field in wire_only, name
