"""A toy fifth protocol, out of tree, used to prove that a protocol's tool support is its
plug-in files plus one table entry (docs/architecture.md, "Adding a protocol").

Its plug-ins live under this package exactly as the built-in ones live under fap_py:
``toyproto/monitor/protocols/toy.py``, ``toyproto/bridge/protocols/toy.py``,
``toyproto/soak/toy.py``, ``toyproto/commands/protocols/toy.py``.
"""
