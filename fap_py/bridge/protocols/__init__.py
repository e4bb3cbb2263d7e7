"""Each protocol's bridge plug-in: ``fap_py.bridge.protocols.<name>``, the protocol's
one name in the protocol table (``fap_py._protocols``), which finds it by name::

    _protocols.get("exec").plugin("bridge")

A plug-in module holds what the bridge knows of its protocol and nothing else does:

* ``ROLES``: the roles a bus of this protocol may take (``("master",)``, or with ``"slave"``);
* ``DEFAULT_TIMEOUT``: the bus's ``timeout`` when the file gives none;
* ``options(table, where, role, proto)``: takes the protocol's own keys out of a
  ``[[bus]]`` table, checks them (``fap_py.bridge._schema``; node ranges from ``proto``,
  the table row) and returns them as a frozen dataclass, the bus's ``options``;
* ``Adapter``: a :class:`fap_py.bridge.buses.BusAdapter` that runs the protocol's
  engine, with ``HEALTH`` naming its engine counters behind the neutral health counters.

A fifth protocol's bridge support is one such file (docs/architecture.md).
"""
