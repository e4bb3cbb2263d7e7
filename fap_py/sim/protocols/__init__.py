"""The sim's per-protocol plug-ins, one module per protocol of the table, found by name:
``fap_py.sim.plugin("exec")`` imports ``fap_py.sim.protocols.exec`` (docs/sim.md, "Plug-ins").

A plug-in holds ``NAME``, ``ADDRESS_MIN``/``ADDRESS_MAX`` (and ``ADDRESS_RESERVED``),
``FAULTS`` (the fault kinds it implements), ``NODE_PROPERTIES`` (its node keys, JSON Schema),
``check_node(node, where) -> [Problem]`` and ``start(bus, ctx) -> runner`` (an object with
``stop()`` and ``status() -> {address: counters}``). A request/reply protocol's runner is
:class:`fap_py.sim.responder.Responder`, which asks the plug-in for ``request_decoder(baud)``,
``bad_check(frame)``, ``wrong_address(frame, address, request)`` and ``garbage(rng, n)``.
"""
