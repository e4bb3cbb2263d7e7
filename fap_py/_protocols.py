"""The protocol table: every protocol's one name, its aliases, pcap id and binding module.

This is the one place that lists the protocols. Every tool finds its per-protocol part
*by name* through it (pyserial's URL handlers, Wireshark's dissectors)::

    get("exec").plugin("monitor")   # imports fap_py.monitor.protocols.exec

so a fifth protocol's tool support is its plug-in files plus one entry in ``PROTOCOLS``
(docs/architecture.md has the recipe). Numbers (address range, broadcast address,
default baud) are never re-typed by a tool: they are read from the binding module
(``NODE_MIN``, ``NODE_MAX``, ``BROADCAST``, ``DEFAULT_BAUD``), which reads them from C
where C defines them.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Dict, Optional, Tuple

from .errors import InvalidValueError

__all__ = ["ENV_EXTRA", "TOOLS", "PROTOCOLS", "Protocol", "UnknownProtocolError", "get", "names", "all_protocols",
           "register", "unregister"]

#: Each tool's plug-in package, relative to a protocol's ``package``:
#: the plug-in of protocol ``name`` for tool ``t`` is ``<package>.<TOOLS[t]>.<name>``.
TOOLS: Dict[str, str] = {
    "monitor": "monitor.protocols",
    "bridge": "bridge.protocols",
    "soak": "soak",
    "cli": "commands.protocols",
    "sim": "sim.protocols",
}


class UnknownProtocolError(InvalidValueError):
    """A protocol name (or alias) that is not in the table, or a tool without a plug-in."""


@dataclass(frozen=True)
class Protocol:
    """One row of the table.

    ``name`` is the one spelling every tool prints and writes; ``aliases`` are accepted
    on input only (old configs, old command lines). ``binding`` is the protocol's own
    room (its codec and nodes, and the constants the tools read). ``package`` is the
    root under which the tool plug-ins live: ``fap_py`` for the built-in protocols.
    """

    name: str
    title: str
    pcap_id: int
    binding: str
    aliases: Tuple[str, ...] = ()
    package: str = "fap_py"

    def module(self) -> ModuleType:
        """The binding module (imported on first use)."""
        return importlib.import_module(self.binding)

    def plugin_name(self, tool: str) -> str:
        """The dotted module name of this protocol's plug-in for ``tool``."""
        try:
            room = TOOLS[tool]
        except KeyError:
            raise UnknownProtocolError(f"unknown tool {tool!r} (tools: {', '.join(TOOLS)})") from None
        return f"{self.package}.{room}.{self.name}"

    def plugin(self, tool: str) -> ModuleType:
        """Import and return this protocol's plug-in module for ``tool``."""
        mod_name = self.plugin_name(tool)
        try:
            return importlib.import_module(mod_name)
        except ModuleNotFoundError as e:
            if e.name is None or not (mod_name == e.name or mod_name.startswith(e.name + ".")):
                raise  # the plug-in exists but one of *its* imports is missing
            raise UnknownProtocolError(f"protocol {self.name!r} has no {tool} plug-in ({mod_name})") from None

    def has_plugin(self, tool: str) -> bool:
        """True when ``plugin(tool)`` would import."""
        try:
            return importlib.util.find_spec(self.plugin_name(tool)) is not None
        except ModuleNotFoundError:  # a parent package is missing
            return False

    def _fact(self, attr: str) -> Any:
        return getattr(self.module(), attr)

    @property
    def node_min(self) -> int:
        """Lowest node address/ID a master talks to (from the binding module)."""
        return int(self._fact("NODE_MIN"))

    @property
    def node_max(self) -> int:
        """Highest node address/ID a master talks to (from the binding module)."""
        return int(self._fact("NODE_MAX"))

    @property
    def broadcast(self) -> Optional[int]:
        """The broadcast address, or None when the protocol has none."""
        b = self._fact("BROADCAST")
        return None if b is None else int(b)

    @property
    def default_baud(self) -> int:
        """The baud rate a tool uses when none is given."""
        return int(self._fact("DEFAULT_BAUD"))


#: The table. Order is the order tools list protocols in (help texts, `--protocol all`).
PROTOCOLS: Tuple[Protocol, ...] = (
    Protocol("fap", "Fast Action Protocol", 1, "fap_py.fap"),
    Protocol("exec", "exec async protocol", 2, "fap_py.execasync", aliases=("execasync",)),
    Protocol("mikroc", "mikroC RS-485 library", 3, "fap_py.mikroc"),
    Protocol("g485", "Gicren G485", 4, "fap_py.g485"),
)

#: Out-of-tree protocols: ``module:ATTR`` references (comma-separated) to Protocol rows,
#: loaded on first use of the table. A child process (a soak child, the CLI run as a
#: program) inherits them through the environment, as it inherits PYTHONPATH.
ENV_EXTRA = "FAP_EXTRA_PROTOCOLS"

_extra: Dict[str, Protocol] = {}
_env_loaded = False


def _load_env() -> None:
    global _env_loaded
    _env_loaded = True
    for ref in filter(None, (r.strip() for r in os.environ.get(ENV_EXTRA, "").split(","))):
        mod, _, attr = ref.partition(":")
        try:
            row = getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError, ValueError) as e:
            raise UnknownProtocolError(f"{ENV_EXTRA}: cannot load {ref!r}: {e}") from None
        if row.name not in _extra:
            register(row)


def all_protocols() -> Tuple[Protocol, ...]:
    """The table plus protocols added with ``register`` or ``FAP_EXTRA_PROTOCOLS``."""
    if not _env_loaded:
        _load_env()
    return PROTOCOLS + tuple(_extra.values())


def names() -> Tuple[str, ...]:
    """Every protocol's one name, in table order."""
    return tuple(p.name for p in all_protocols())


def get(name: str) -> Protocol:
    """The protocol called ``name`` or one of its aliases (case-insensitive)."""
    if not isinstance(name, str):
        raise UnknownProtocolError(f"protocol name must be a str, not {type(name).__name__}")
    key = name.strip().lower()
    for p in all_protocols():
        if key == p.name or key in p.aliases:
            return p
    raise UnknownProtocolError(f"unknown protocol {name!r} (protocols: {', '.join(names())})")


def register(p: Protocol) -> None:
    """Add a protocol outside the built-in table (a test's toy protocol, an out-of-tree one)."""
    if not isinstance(p, Protocol):
        raise UnknownProtocolError(f"register() takes a Protocol, not {type(p).__name__}")
    taken = {q.name for q in all_protocols()} | {a for q in all_protocols() for a in q.aliases}
    if p.name in taken or taken & set(p.aliases):
        raise UnknownProtocolError(f"protocol {p.name!r} (or an alias) is already registered")
    if p.pcap_id in {q.pcap_id for q in all_protocols()}:
        raise UnknownProtocolError(f"pcap id {p.pcap_id} is already used")
    _extra[p.name] = p


def unregister(name: str) -> None:
    """Remove a protocol added with ``register`` (the built-in table cannot shrink)."""
    if name not in _extra:
        raise UnknownProtocolError(f"protocol {name!r} was not added with register()")
    del _extra[name]
