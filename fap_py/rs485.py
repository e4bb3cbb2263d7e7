"""RS-485 line options, the same for every protocol (``fap_port_options``).

Every node that opens a port through libfap's C port layer (FAP, exec async,
mikroC, the G485 Port) takes an :class:`RS485`. Its defaults are the C
layer's own (``fap_port_options_init``), read from the compiled core when
the node opens the port: a field left at ``None`` is never written, so
there is one set of defaults, C's.
"""
from __future__ import annotations

import enum
import os
from dataclasses import dataclass
from typing import Any, Dict, Optional

from ._native import ffi, lib
from ._validate import U32, baud_rates, check_baud, check_int
from .errors import InvalidTypeError, InvalidValueError

__all__ = ["DEFAULT_BAUD", "RS485", "RS485Mode", "port_options", "line_options", "c_defaults",
           "parse_realtime", "baud_rates", "check_rate"]


class RS485Mode(enum.IntEnum):
    """How the transmitter is switched (``fap_rs485_mode``)."""

    AUTO = lib.FAP_RS485_AUTO          #: kernel RS-485 if the driver has it, else NONE
    KERNEL = lib.FAP_RS485_KERNEL      #: TIOCSRS485: the kernel toggles RTS
    SOFT_RTS = lib.FAP_RS485_SOFT_RTS  #: assert RTS, write, tcdrain(), release RTS
    NONE = lib.FAP_RS485_NONE          #: auto-direction transceiver, USB adapter, pty
    GPIO = lib.FAP_RS485_GPIO          #: a GPIO line (gpio_chip, gpio_line) is the DE/RE pin

    def __str__(self) -> str:
        """The name (``print(node.rs485_mode)`` shows ``NONE``, not ``3``)."""
        return self.name

    def __format__(self, spec: str) -> str:
        """``f"{mode}"`` is the name too; ``f"{mode:d}"`` the number."""
        return format(int(self) if spec[-1:] in ("d", "x", "X", "o", "b", "n") else self.name,
                      spec)

    @classmethod
    def _missing_(cls, value: object) -> "Optional[RS485Mode]":
        """A name, any case (``"none"``, ``"SOFT_RTS"``; ``"soft"`` as the CLI says)."""
        if isinstance(value, str):
            key = value.strip().upper().replace("-", "_")
            return cls.__members__.get("SOFT_RTS" if key == "SOFT" else key)
        return None


_INT_FIELDS = ("delay_before_send_us", "delay_after_send_us", "echo_timeout_us",
               "turnaround_us", "write_timeout_us", "gpio_line")
# gpio_chip paths handed to C: kept for the life of the process (C copies
# the path at open, but an options struct may be used long after the RS485
# that filled it is gone; a machine has a handful of gpiochips)
_CHIP_PATHS: Dict[bytes, Any] = {}
_BOOL_FIELDS = ("rts_active_high", "rx_during_tx", "echo_suppression", "exclusive",
                "low_latency")


def c_defaults() -> Dict[str, Any]:
    """The C port layer's defaults (``fap_port_options_init``) by RS485 field
    name: what a field left at None means."""
    po = ffi.new("fap_port_options *")
    lib.fap_port_options_init(po)
    out: Dict[str, Any] = {"mode": RS485Mode(po.rs485_mode)}
    out.update({name: int(getattr(po, name)) for name in _INT_FIELDS})
    out.update({name: int(getattr(po, name)) for name in _BOOL_FIELDS})
    out["gpio_chip"] = None if po.gpio_chip == ffi.NULL else ffi.string(po.gpio_chip).decode()
    rt = po.rt   # the real-time option: all off unless asked (docs/realtime.md)
    out["realtime"] = "off" if not (rt.policy or rt.priority or rt.mlock or rt.cpus) else None
    return out


def _c_default_baud() -> int:
    po = ffi.new("fap_port_options *")
    lib.fap_port_options_init(po)
    return int(po.baud)


#: The C layer's default baud rate (``fap_port_options_init``).
DEFAULT_BAUD: int = _c_default_baud()
_PO_TYPE = ffi.typeof("fap_port_options *")


@dataclass(frozen=True)
class RS485:
    """RS-485 line options of a node (``fap_port_options``).

    Every field left at ``None`` keeps the C port layer's default (what
    ``fap_port_options_init`` sets; :func:`c_defaults` lists them): Python
    has no defaults of its own. Times are integer microseconds, as the C
    layer takes them (the kernel rounds its RTS delays up to milliseconds).
    """

    mode: Optional[RS485Mode] = None             #: direction control (C default AUTO)
    rts_active_high: Optional[bool] = None       #: RTS level while sending
    delay_before_send_us: Optional[int] = None   #: RTS asserted -> first bit
    delay_after_send_us: Optional[int] = None    #: last bit -> RTS released
    rx_during_tx: Optional[bool] = None          #: kernel mode: receiver on while sending
    echo_suppression: Optional[bool] = None      #: read back and drop our own bytes
    echo_timeout_us: Optional[int] = None        #: wait for the echo (0 = C's rule)
    turnaround_us: Optional[int] = None          #: quiet time after the last byte received
    exclusive: Optional[bool] = None             #: TIOCEXCL + flock: refuse a second opener
    write_timeout_us: Optional[int] = None       #: longest write (0 = C's rule)
    gpio_chip: Optional[str] = None              #: GPIO mode: DE/RE line's /dev/gpiochipN
    gpio_line: Optional[int] = None              #: GPIO mode: line offset on gpio_chip
    low_latency: Optional[bool] = None           #: FTDI latency_timer 1 ms while open
                                                 #: (C default: in soft-RTS and GPIO modes)
    realtime: Optional[str] = None               #: real-time spec of the engine's I/O thread,
                                                 #: e.g. "fifo:50,mlock,cpu=1" (docs/realtime.md)

    def __post_init__(self) -> None:
        if self.mode is not None:
            if isinstance(self.mode, bool) or not isinstance(self.mode, (int, str)):
                raise InvalidTypeError(f"RS485.mode must be an RS485Mode or its name, "
                                       f"not {self.mode!r}")
            try:
                object.__setattr__(self, "mode", RS485Mode(self.mode))
            except ValueError as exc:
                raise InvalidValueError(f"RS485.mode must be an RS485Mode or its name "
                                        f"({', '.join(m.name.lower() for m in RS485Mode)}), "
                                        f"not {self.mode!r}") from exc
        for name in _INT_FIELDS:
            if getattr(self, name) is not None:
                check_int(getattr(self, name), f"RS485.{name}", 0, U32)
        for name in _BOOL_FIELDS:
            if getattr(self, name) is not None and not isinstance(getattr(self, name), bool):
                raise InvalidTypeError(f"RS485.{name} must be a bool or None")
        if self.gpio_chip is not None:
            if not isinstance(self.gpio_chip, (str, os.PathLike)):
                raise InvalidTypeError(f"RS485.gpio_chip must be a path, not {self.gpio_chip!r}")
            if not os.fspath(self.gpio_chip) or "\0" in os.fspath(self.gpio_chip):
                raise InvalidValueError("RS485.gpio_chip must be a non-empty path")
        if self.mode == RS485Mode.GPIO and self.gpio_chip is None:
            raise InvalidValueError("RS485.mode GPIO needs RS485.gpio_chip (e.g. '/dev/gpiochip0')")
        if self.realtime is not None:
            parse_realtime(self.realtime, "RS485.realtime")   # C's parser says what is wrong

    def apply_to(self, po: Any, baudrate: int) -> Any:
        """Set ``baudrate`` and the fields given (not None) in a cffi
        ``fap_port_options *`` that ``fap_port_options_init`` (or
        ``fapx_options_init``) prepared; the others keep C's defaults.

        The one place that maps Python line options onto the C port layer.
        """
        if not isinstance(po, ffi.CData) or ffi.typeof(po) is not _PO_TYPE:
            raise InvalidTypeError(f"po must be a cffi 'fap_port_options *', not {po!r}")
        po.baud = check_rate(baudrate)
        if self.mode is not None:
            po.rs485_mode = int(self.mode)
        for name in _INT_FIELDS:
            if getattr(self, name) is not None:
                setattr(po, name, getattr(self, name))
        for name in _BOOL_FIELDS:
            if getattr(self, name) is not None:
                setattr(po, name, int(getattr(self, name)))
        if self.gpio_chip is not None:
            path = os.fsencode(self.gpio_chip)
            if path not in _CHIP_PATHS:
                _CHIP_PATHS[path] = ffi.new("char[]", path)
            po.gpio_chip = _CHIP_PATHS[path]
        if self.realtime is not None:
            po.rt = parse_realtime(self.realtime, "RS485.realtime")[0]
        return po


def parse_realtime(spec: str, what: str = "") -> Any:
    """A cffi ``fap_port_rt *`` from a real-time spec (``"fifo:50,mlock,cpu=1"``,
    ``"off"``), parsed by C's one parser (``fap_port_rt_parse``); raises
    :class:`InvalidValueError` naming ``what`` (when given) and the bad item."""
    head = f"{what}: " if what else ""
    if not isinstance(spec, str):
        raise InvalidTypeError(f"{what or 'realtime'} must be a real-time spec string, "
                               f"not {spec!r}")
    if "\0" in spec or not spec.isascii():
        raise InvalidValueError(f"{head}the real-time spec {spec!r} is not plain ASCII text")
    rt = ffi.new("fap_port_rt *")
    why = ffi.new("char[]", 200)
    if lib.fap_port_rt_parse(spec.encode(), rt, why, len(why)) < 0:
        raise InvalidValueError(f"{head}{ffi.string(why).decode()}")
    return rt


def line_options(rs485: Optional[RS485]) -> RS485:
    """``rs485`` checked; ``None`` = the port layer's defaults."""
    if rs485 is None:
        return RS485()
    if not isinstance(rs485, RS485):
        raise InvalidTypeError(f"rs485 must be an RS485, not {type(rs485).__name__}")
    return rs485


def check_rate(value: Any, what: str = "baudrate") -> int:
    """``value`` if it is one of :func:`baud_rates`; else InvalidTypeError /
    InvalidValueError naming the rates (what ``fap_port_open`` would refuse
    with EINVAL, refused before anything reaches C). The rule is
    :func:`fap_py._validate.check_baud`'s."""
    return check_baud(value, what)


def port_options(baudrate: int, rs485: Optional[RS485] = None) -> Any:
    """A new cffi ``fap_port_options *`` for ``baudrate`` (one of
    :func:`baud_rates`) and ``rs485``. Raises before anything reaches C."""
    baudrate = check_rate(baudrate)
    opts = line_options(rs485)
    po = ffi.new("fap_port_options *")
    lib.fap_port_options_init(po)
    return opts.apply_to(po, baudrate)
