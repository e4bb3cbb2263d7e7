"""The protocol table (fap_py._protocols): one name per protocol, aliases, facts, plug-in lookup."""

import pytest

from fap_py import _protocols as P
from fap_py.errors import InvalidValueError


def test_every_protocol_has_one_name_and_a_unique_pcap_id():
    names = P.names()
    assert names == ("fap", "exec", "mikroc", "g485")
    assert len({p.pcap_id for p in P.PROTOCOLS}) == len(P.PROTOCOLS)


def test_aliases_resolve_to_the_one_name():
    assert P.get("execasync").name == "exec"
    assert P.get(" EXEC ").name == "exec"


def test_facts_come_from_the_binding_modules():
    from fap_py import execasync, fap, g485, mikroc, rs485
    assert (P.get("fap").node_min, P.get("fap").node_max, P.get("fap").broadcast) == (1, fap.MAX_ID, None)
    assert P.get("exec").broadcast == execasync.BROADCAST
    assert P.get("mikroc").broadcast == mikroc.BROADCAST
    assert (P.get("g485").node_min, P.get("g485").node_max) == (g485.NODE_MIN, g485.NODE_MAX)
    assert P.get("mikroc").default_baud == mikroc.DEFAULT_BAUD == 19200   # the vendor examples' rate
    assert {P.get(n).default_baud for n in ("fap", "exec", "g485")} == {rs485.DEFAULT_BAUD}


@pytest.mark.parametrize("bad", ["modbus", "", 3, None])
def test_unknown_names_raise_the_package_error(bad):
    with pytest.raises(P.UnknownProtocolError) as e:
        P.get(bad)
    assert isinstance(e.value, InvalidValueError)


def test_register_and_unregister_a_protocol():
    toy = P.Protocol("toyproto", "a toy", 99, "fap_py.fap", package="nowhere")
    P.register(toy)
    try:
        assert P.get("toyproto") is toy
        with pytest.raises(P.UnknownProtocolError):
            P.register(toy)
        with pytest.raises(P.UnknownProtocolError, match="no monitor plug-in"):
            toy.plugin("monitor")
        with pytest.raises(P.UnknownProtocolError, match="unknown tool"):
            toy.plugin("nosuchtool")
    finally:
        P.unregister("toyproto")
    with pytest.raises(P.UnknownProtocolError):
        P.get("toyproto")
