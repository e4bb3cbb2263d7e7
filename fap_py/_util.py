"""Small pieces every libfap binding (fap, execasync, mikroc) shares. Private."""
from __future__ import annotations

import math
import time
from dataclasses import fields
from typing import Any, Optional, Type, TypeVar

T = TypeVar("T")
C = TypeVar("C", bound="Closing")


def check_int(value: Any, what: str, lo: int, hi: int, *,
              error: Type[Exception], type_error: Type[Exception]) -> int:
    """``value`` if it is an int (not a bool) in lo..hi; else ``type_error`` / ``error``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise type_error(f"{what} must be an int, not {type(value).__name__}")
    if not lo <= value <= hi:
        raise error(f"{what} must be in {lo}..{hi}, not {value}")
    return int(value)


def from_cdata(cls: Type[T], cdata: Any) -> T:
    """A stats dataclass filled from the C struct fields of the same names."""
    return cls(**{f.name: int(getattr(cdata, f.name)) for f in fields(cls)})  # type: ignore[arg-type]


def slice_ms(deadline: Optional[float], longest_ms: int) -> int:
    """Milliseconds for the next wait inside C: what is left until ``deadline``
    (``time.monotonic()``; None = no deadline), at most ``longest_ms``, so a
    blocked caller notices Ctrl-C and close() between slices."""
    if deadline is None:
        return longest_ms
    return max(0, min(longest_ms, math.ceil((deadline - time.monotonic()) * 1000)))


class Closing:
    """``close()`` on leaving a ``with`` block and when the object is collected."""

    def close(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def __enter__(self: C) -> C:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # a forgotten object must not keep its port or thread
        try:
            self.close()
        except Exception:  # pragma: no cover - half-built object, interpreter shutdown
            pass
