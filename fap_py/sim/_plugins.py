"""Finding a protocol's sim plug-in by name: the protocol table's ``sim`` tool
room (``<package>.sim.protocols.<name>``, :data:`fap_py._protocols.TOOLS`), so
a protocol without one (an out-of-tree protocol that brings no simulator) is
simply not offered, never an import error."""
from __future__ import annotations

from types import ModuleType
from typing import List


def plugin_name(protocol: str) -> str:
    """The module name of ``protocol``'s sim plug-in (its one name or an alias)."""
    from .. import _protocols

    return _protocols.get(protocol).plugin_name("sim")


def plugin(protocol: str) -> ModuleType:
    """Import ``protocol``'s sim plug-in (UnknownProtocolError if it has none)."""
    from .. import _protocols

    return _protocols.get(protocol).plugin("sim")


def simulated() -> List[str]:
    """The protocols of the table that have a sim plug-in, in table order."""
    from .. import _protocols

    return [n for n in _protocols.names() if _protocols.get(n).has_plugin("sim")]
