"""Argument checks shared by every public fap_py API. Private.

Every check raises the package's own exceptions (:mod:`fap_py.errors`):
:class:`~fap_py.errors.InvalidTypeError` for a wrong type (a bool where an
int is wanted, a str where bytes are, an int where bytes are: ``bytes(300)``
would silently be 300 zero bytes) and :class:`~fap_py.errors.InvalidValueError`
for a value out of range (negative, NaN, infinite, too large). Modules with
their own subclasses pass them as ``error`` / ``type_error``.
"""
from __future__ import annotations

import math
import os
from typing import Any, Optional, Type

from .errors import InvalidTypeError, InvalidValueError

__all__ = [
    "U32",
    "INT_MS_MAX",
    "check_int",
    "check_bool",
    "check_bytes",
    "check_seconds",
    "check_probability",
    "check_timeout",
    "check_baud",
    "check_path",
    "check_gpio_line",
    "timeout_ms",
]

U32 = 0xFFFFFFFF
INT_MS_MAX = 0x7FFFFFFF          #: the longest wait a C ``int timeout_ms`` holds
#: Longest timeout any call accepts (seconds): about 24 days, what an int of ms holds.
MAX_TIMEOUT = INT_MS_MAX / 1000.0


def check_int(value: Any, what: str, lo: int, hi: int, *,
              error: Type[Exception] = InvalidValueError,
              type_error: Type[Exception] = InvalidTypeError) -> int:
    """``value`` if it is an int (not a bool) in lo..hi; else ``type_error`` / ``error``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise type_error(f"{what} must be an int, not {type(value).__name__}")
    if not lo <= value <= hi:
        raise error(f"{what} must be in {lo}..{hi}, not {value}")
    return int(value)


def check_bool(value: Any, what: str, *, type_error: Type[Exception] = InvalidTypeError) -> bool:
    """``value`` if it is a bool (an int 0/1 is refused: it is usually a mistake)."""
    if not isinstance(value, bool):
        raise type_error(f"{what} must be a bool, not {type(value).__name__}")
    return value


def check_bytes(data: Any, what: str, lo: int, hi: int, *,
                error: Type[Exception] = InvalidValueError,
                type_error: Type[Exception] = InvalidTypeError) -> bytes:
    """``data`` as bytes if it is a byte buffer of lo..hi bytes.

    Only bytes, bytearray and memoryview pass: ``bytes(300)`` (300 zeros) and
    ``bytes("x")`` (TypeError) are not what the caller meant."""
    if type(data) is bytes:
        payload = data
    elif isinstance(data, (bytes, bytearray, memoryview)):
        payload = bytes(data)
    elif isinstance(data, str):
        raise type_error(f"{what} must be bytes-like, not str (encode it first)")
    else:
        raise type_error(f"{what} must be bytes-like, not {type(data).__name__}")
    if not lo <= len(payload) <= hi:
        raise error(f"{what} must hold {lo}..{hi} bytes, not {len(payload)}")
    return payload


def check_seconds(value: Any, what: str, *, lo: float = 0.0, hi: float = MAX_TIMEOUT,
                  lo_open: bool = False,
                  error: Type[Exception] = InvalidValueError,
                  type_error: Type[Exception] = InvalidTypeError) -> float:
    """A finite number of seconds in lo..hi (``lo_open``: strictly above lo)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise type_error(f"{what} must be a number of seconds, not {type(value).__name__}")
    try:
        v = float(value)
    except OverflowError:      # an int too large for a float
        raise error(f"{what} must be at most {hi} s, not {value}") from None
    if math.isnan(v) or math.isinf(v):
        raise error(f"{what} must be a finite number of seconds, not {value}")
    if v < lo or (lo_open and v == lo):
        raise error(f"{what} must be {'>' if lo_open else '>='} {lo} s, not {value}")
    if v > hi:
        raise error(f"{what} must be at most {hi} s, not {value}")
    return v


def check_probability(value: Any, what: str, *,
                      error: Type[Exception] = InvalidValueError,
                      type_error: Type[Exception] = InvalidTypeError) -> float:
    """A probability: a finite number in 0..1 (no unit: not "at most 1.0 s")."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise type_error(f"{what} must be a probability (a number in 0..1), "
                         f"not {type(value).__name__}")
    try:
        v = float(value)
    except OverflowError:
        v = math.inf
    if not 0.0 <= v <= 1.0:      # NaN fails both
        raise error(f"{what} must be a probability in 0..1, not {value}")
    return v


def check_timeout(value: Any, what: str = "timeout", **kw: Any) -> Optional[float]:
    """A timeout in seconds, or None (= wait as long as it takes)."""
    return None if value is None else check_seconds(value, what, **kw)


def timeout_ms(value: Any, what: str = "timeout", **kw: Any) -> int:
    """A checked timeout as C milliseconds: -1 for None, else rounded up."""
    t = check_timeout(value, what, **kw)
    return -1 if t is None else min(math.ceil(t * 1000.0), INT_MS_MAX)


def baud_rates() -> "tuple[int, ...]":
    """The rates the C port layer opens a line at (its termios table,
    ``fap_port_baud_rate()``), ascending."""
    global _BAUD_RATES
    if _BAUD_RATES is None:
        from ._native import lib

        rates: "list[int]" = []
        while True:
            r = int(lib.fap_port_baud_rate(len(rates)))
            if r == 0:
                break
            rates.append(r)
        _BAUD_RATES = tuple(rates)
    return _BAUD_RATES


_BAUD_RATES: "Optional[tuple[int, ...]]" = None


def check_baud(value: Any, what: str = "baudrate", *,
               error: Type[Exception] = InvalidValueError, **kw: Any) -> int:
    """An int baud rate of the C port layer's table (:func:`baud_rates`): a
    rate termios lacks is refused here, naming the rate and the valid ones,
    rather than as C's bare ``open: invalid argument``."""
    value = check_int(value, what, 1, U32, error=error, **kw)
    rates = baud_rates()
    if rates and value not in rates:
        raise error(f"{what} {value} is not a supported rate; supported: "
                    f"{', '.join(map(str, rates))}")
    return value


def check_path(port: Any, what: str = "port", *,
               type_error: Type[Exception] = InvalidTypeError,
               error: Type[Exception] = InvalidValueError) -> str:
    """A device path (str, bytes or os.PathLike) as str; empty and NUL refused."""
    if not isinstance(port, (str, bytes, os.PathLike)):
        raise type_error(f"{what} must be a path, not {type(port).__name__}")
    path = os.fsdecode(os.fspath(port))
    if not path or "\0" in path:
        raise error(f"{what} must be a non-empty path without NUL bytes, not {path!r}")
    return path


#: lines a GPIO DE/RE pin may use: the C port layer's bound (port_gpio.c: offsets < 512)
GPIO_LINES_MAX = 512
#: linux/gpio.h GPIO_GET_CHIPINFO_IOCTL: _IOR(0xB4, 0x01, struct gpiochip_info), 68 bytes
_GPIO_GET_CHIPINFO = 0x8044B401


def check_gpio_line(chip: Any, line: Any) -> int:
    """The RS-485 GPIO mode's DE/RE line, checked before the port opens so an
    error names the chip, not the serial port: ``chip`` a GPIO character
    device (it is opened and asked for its line count, GPIO_GET_CHIPINFO),
    ``line`` an offset below that count (and below 512, the C bound).
    Returns the chip's line count. Raises InvalidValueError (a bad line) or
    FileError naming the chip (missing, not permitted, not a GPIO chip)."""
    import errno
    import fcntl
    import struct

    from .errors import FileError

    path = check_path(chip, "gpio_chip")
    check_int(line, "gpio_line", 0, U32)
    if line >= GPIO_LINES_MAX:
        raise InvalidValueError(f"gpio_line {line}: a GPIO line offset is 0..{GPIO_LINES_MAX - 1}")
    def fail(err: int, why: str) -> "FileError":
        exc = FileError(err, why, path)
        exc.why = why
        return exc

    try:
        fd = os.open(path, os.O_RDWR | os.O_CLOEXEC | os.O_NOCTTY)
    except OSError as exc:
        raise fail(exc.errno or errno.EIO, f"cannot open the GPIO chip ({exc.strerror})") from None
    try:
        info = bytearray(68)
        fcntl.ioctl(fd, _GPIO_GET_CHIPINFO, info)
    except OSError as exc:
        raise fail(exc.errno or errno.ENOTTY, "not a GPIO character device (GPIO_GET_CHIPINFO "
                   f"refused: {exc.strerror}); give /dev/gpiochipN") from None
    finally:
        os.close(fd)
    lines = struct.unpack_from("=I", info, 64)[0]
    if line >= lines:
        raise InvalidValueError(f"gpio_line {line}: {path} has {lines} lines "
                                f"(0..{max(lines, 1) - 1})")
    return int(lines)
