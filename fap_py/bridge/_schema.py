"""The checking helpers of bridge.toml, shared by the common keys (config.py) and each
protocol's own keys (``protocols/<name>.py``): pop a key of a type, check a range, refuse
what is left. Every error is a :class:`BridgeConfigError` naming the key."""
from __future__ import annotations

from typing import Any, Dict, Tuple

from .._protocols import Protocol
from ..errors import InvalidTypeError, InvalidValueError

__all__ = ["BridgeConfigError", "BridgeConfigTypeError", "show", "pop", "in_range", "done", "id_list",
           "hex_bytes", "check_plugin_args"]


class BridgeConfigError(InvalidValueError):
    """The bridge configuration is missing a key, has an unknown one, or a bad value."""


class BridgeConfigTypeError(BridgeConfigError, InvalidTypeError):
    """A configuration reader was handed something of the wrong type (not a path, not a table)."""


def check_plugin_args(t: Any, where: Any, role: Any, proto: Any) -> None:
    """What a plug-in's ``options(t, where, role, proto)`` is handed: a table (dict), the
    bus's name for errors and its role (str), and the protocol's table row."""
    if not isinstance(t, dict):
        raise BridgeConfigTypeError(f"a bus table must be a dict, not {type(t).__name__}")
    if not isinstance(where, str) or not isinstance(role, str):
        raise BridgeConfigTypeError("where and role must be str")
    if not isinstance(proto, Protocol):
        raise BridgeConfigTypeError(f"proto must be a protocol table row, not {type(proto).__name__}")


def show(value: Any, limit: int = 60) -> str:
    """A value for an error line: bounded (a 1 MB string or a 10,000-digit number is not echoed)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 64:
        return f"a {value.bit_length()}-bit integer"
    try:
        text = repr(value)
    except ValueError:   # an int inside a list past Python's digit limit
        text = f"a {type(value).__name__}"
    return text if len(text) <= limit else text[:limit] + "..."


def pop(table: Dict[str, Any], key: str, kind: Any, where: str, default: Any = ...) -> Any:
    """Remove ``key`` from ``table`` and return it, checked to be of ``kind`` (a bool is
    no number); ``default`` when absent (missing and no default: an error)."""
    if key not in table:
        if default is ...:
            raise BridgeConfigError(f"{where}: missing key {show(key)}")
        return default
    value = table.pop(key)
    ok = isinstance(value, kind) and not (isinstance(value, bool) and kind in (int, float, (int, float)))
    if not ok:
        name = kind.__name__ if isinstance(kind, type) else "/".join(k.__name__ for k in kind)
        raise BridgeConfigError(f"{where}.{key}: expected {name}, got {show(value)}")
    if kind == (int, float) and isinstance(value, int) and abs(value) > 1e300:   # float() would overflow
        raise BridgeConfigError(f"{where}.{key}: {show(value)} is out of range")
    return value


def in_range(value: Any, lo: float, hi: float, what: str) -> Any:
    """``value`` if ``lo <= value <= hi``."""
    if not lo <= value <= hi:
        raise BridgeConfigError(f"{what} must be in {lo}..{hi}, not {show(value)}")
    return value


def done(table: Dict[str, Any], where: str) -> None:
    """Every key was taken: what is left is unknown (a typo is named, not ignored)."""
    if table:
        raise BridgeConfigError(f"{where}: unknown key(s) {', '.join(sorted(table))[:200]}")


def id_list(values: Any, lo: int, hi: int, what: str) -> Tuple[int, ...]:
    """A list of distinct integers in ``lo..hi``."""
    if not isinstance(values, list) or not all(isinstance(v, int) and not isinstance(v, bool)
                                               for v in values):
        raise BridgeConfigError(f"{what} must be a list of integers")
    for v in values:
        in_range(v, lo, hi, what)
    if len(set(values)) != len(values):
        raise BridgeConfigError(f"{what} lists an ID twice: {show(values)}")
    return tuple(values)


def hex_bytes(t: Dict[str, Any], key: str, where: str) -> "bytes | None":
    """An optional hex string key as bytes (None when absent)."""
    data = pop(t, key, str, where, None)
    if data is None:
        return None
    try:
        return bytes.fromhex(data)
    except ValueError:
        raise BridgeConfigError(f"{where}.{key} is not hex: {show(data)}") from None
