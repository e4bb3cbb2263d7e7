"""The sim's per-protocol plug-ins, one module per protocol of the table, found by name:
``fap_py.sim.plugin("exec")`` imports ``fap_py.sim.protocols.exec`` (docs/sim.md, "Plug-ins").

A plug-in holds ``NAME``, ``ADDRESS_MIN``/``ADDRESS_MAX`` (and ``ADDRESS_RESERVED``),
``FAULTS`` (the fault kinds it implements), ``NODE_PROPERTIES`` (its node keys, JSON Schema),
``check_node(node, where) -> [Problem]`` and ``start(bus, ctx) -> runner`` (an object with
``stop()`` and ``status() -> {address: counters}``). A request/reply protocol's runner is the
sim's shared responder, which asks the plug-in for ``request_decoder(baud)``,
``bad_check(frame)``, ``wrong_address(frame, address, request)`` and ``garbage(rng, n)``, and
``error_reply(node, word)`` where its protocol has an error answer (``error_reply`` in ``FAULTS``).
``REPLY_KINDS`` is what the shared responder does to any such protocol: ``FAULTS`` starts there.

This package is also the one documented place of what a plug-in (in tree or out of tree, in
``<package>.sim.protocols``) imports from the sim: the names below. The modules they come from
are private. A plug-in is the sim's own internals: the sim calls it with a checked config
(``fap_py.sim.load``), so the hostile walk does not walk it as public API (its EXCLUDED entry in
tests/python/hostile/walk_runner.py says why); ``fap_py.sim.Sim`` in front of it is walked.
"""
from __future__ import annotations

from .._faults import REPLY_KINDS
from .._generators import Generator, make, to_bytes
from .._responder import CodecFramer, Request, Responder, flip_to, garbage_without
from .._schema import HEX, MAX_LIST, MAX_TABLE, PATTERN, Path, Problem

__all__ = ["CodecFramer", "Generator", "HEX", "MAX_LIST", "MAX_TABLE", "PATTERN", "Path", "Problem",
           "REPLY_KINDS", "Request", "Responder", "flip_to", "garbage_without", "make", "to_bytes"]
