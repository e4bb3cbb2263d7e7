"""The one way fap_py publishes counters: a frozen dataclass built from the C struct. Private.

The contract (docs/python.md, "Counters"): every node has a ``stats``
*property* returning a frozen :class:`Counters` dataclass, a snapshot taken
when the property is read. Each stats dataclass (``fap_py.fap.Stats``,
``fap_py.execasync.MasterStats`` ...) names exactly the fields of its C
struct; :func:`stats_from_c` copies them, and tests/python/test_package.py
checks that the names match the C struct's, so a counter added in C cannot
be forgotten in Python.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Dict, Type, TypeVar

__all__ = ["Counters", "stats_from_c"]

C = TypeVar("C", bound="Counters")


@dataclass(frozen=True)
class Counters:
    """Base of every stats snapshot: frozen, compared and printed as a dataclass."""

    def as_dict(self) -> Dict[str, Any]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def stats_from_c(cls: Type[C], cdata: Any) -> C:
    """A stats dataclass filled from the C struct fields of the same names."""
    return cls(**{f.name: int(getattr(cdata, f.name)) for f in fields(cls)})
