"""``with obj:`` for the package's objects that have a ``close()``. Private.

One mixin instead of the same ``__enter__`` / ``__exit__`` pair in every class
that owns a file, a port or a database: ``with`` gives the object itself and
calls its ``close()`` on the way out, whatever ends the block.
"""
from __future__ import annotations

from typing import TypeVar

__all__ = ["Closing"]

_T = TypeVar("_T", bound="Closing")


class Closing:
    """Mixin: a context manager that returns ``self`` and calls :meth:`close` at exit."""

    def close(self) -> None:  # pragma: no cover - every user defines its own
        raise NotImplementedError

    def __enter__(self: _T) -> _T:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
