"""The toy's tool support is its plug-in files plus its table row: every tool of the table
finds a toy plug-in, under the toy's own package, with nothing added to fap_py."""

import pathlib

import pytest

import fap_py
from fap_py import _protocols


@pytest.mark.parametrize("tool", sorted(_protocols.TOOLS))
def test_every_tool_finds_the_toy_plugin_outside_fap_py(toy_protocol, tool):
    mod = _protocols.get("toy").plugin(tool)
    assert mod.__name__ == f"toyproto.{_protocols.TOOLS[tool]}.toy"
    pkg = pathlib.Path(fap_py.__file__).resolve().parent
    assert pkg not in pathlib.Path(mod.__file__).resolve().parents
    assert not any(p.stem == "toy" for p in pkg.rglob("*.py"))
