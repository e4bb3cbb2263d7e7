"""Fault soak engine: a protocol's master in this process, its slaves in child processes on the
paced virtual bus with bit errors and byte drops, one slave killed and restarted, the master's
port disconnected and back (``fap soak`` is its command line; docs/reliability.md has figures).

:mod:`fap_py.soak.harness` is the protocol-free part (configuration, fault plan, resource
sampler, child processes, bit-error channel model). Each protocol's part is its plug-in
``fap_py.soak.<name>``, found by name through the protocol table::

    from fap_py import _protocols, soak
    for name in _protocols.names():
        print(soak.run(name, soak.Config(seconds=10))["ok"])

A plug-in module has ``run(cfg) -> dict`` (one JSON-able report with ``"protocol"`` and the
verdict ``"ok"``) and ``child(path, node, baud, seed, rate, until) -> int`` (a slave process's
body); an optional ``duration(cfg) -> float`` says how long ``run`` takes when that is more
than ``cfg.seconds``; ``report(result) -> list`` gives the summary lines of a report (``.ci/soak.sh``
prints each protocol's own); an optional ``CHECK8 = True`` marks a protocol whose frames carry
only an 8-bit check (its corruption is measured, not failed on; CI gives it the shorter run).
"""
from __future__ import annotations

from typing import Any, Dict

from .harness import Config, duration

__all__ = ["Config", "run", "duration"]


def run(protocol: str, cfg: Config) -> Dict[str, Any]:
    """Soak ``protocol`` (its name or an alias) with ``cfg``; its report."""
    from .. import _protocols

    result: Dict[str, Any] = _protocols.get(protocol).plugin("soak").run(cfg)
    return result
