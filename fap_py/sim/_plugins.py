"""Finding a protocol's sim plug-in by name (``fap_py.sim.protocols.<name>``)."""
from __future__ import annotations

import importlib
from types import ModuleType


def plugin_name(protocol: str) -> str:
    """The module name of ``protocol``'s sim plug-in (its one name or an alias)."""
    from .. import _protocols

    p = _protocols.get(protocol)
    return f"{p.package}.sim.protocols.{p.name}"


def plugin(protocol: str) -> ModuleType:
    """Import ``protocol``'s sim plug-in."""
    return importlib.import_module(plugin_name(protocol))
