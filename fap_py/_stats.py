"""The one way fap_py publishes counters: a frozen dataclass built from the C struct. Private.

Each stats dataclass (``fap_py.fap.Stats``, ``fap_py.execasync.MasterStats``
...) names exactly the fields of its C struct; :func:`stats_from_c` copies
them, and tests/python/test_package.py checks that the names match the C
struct's, so a counter added in C cannot be forgotten in Python.
"""
from __future__ import annotations

from dataclasses import fields
from typing import Any, Type, TypeVar

__all__ = ["stats_from_c"]

T = TypeVar("T")


def stats_from_c(cls: Type[T], cdata: Any) -> T:
    """A stats dataclass filled from the C struct fields of the same names."""
    return cls(**{f.name: int(getattr(cdata, f.name)) for f in fields(cls)})  # type: ignore[arg-type]
