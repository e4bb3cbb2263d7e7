"""Self-verifying direction control: when does the port release the line,
against the last byte the transceiver echoed back?

With a 2-wire transceiver whose receiver stays on while sending (RX during
TX), every byte sent comes back. The check sends a test pattern several
times through the C port layer (``fap_port_check_direction``: echo
suppression off, the echo read on a second thread) and compares the moment the write returned (soft
RTS / GPIO: after the line was released; other modes: after ``tcdrain``)
with the moment the last echoed byte was read, both on the C layer's
``CLOCK_MONOTONIC``. A negative margin means the port let go of the line
before its own last byte came back: ``tcdrain`` returned early (a USB
adapter's FIFO, a pty) and a soft-RTS transceiver would cut the frame.

:func:`judge` is pure (measurements in, verdict out); :func:`measure` does the I/O.
Times read in userspace include the receive path's latency (FIFO timeout,
USB polling): the margin is a bound, not the pin's edge.
"""
from __future__ import annotations

import dataclasses
import logging
import statistics
from dataclasses import dataclass, field
from typing import Optional, Tuple

from ._validate import U32, check_baud, check_bool, check_int, check_path, check_seconds
from .errors import InvalidTypeError
from .port import Port, port_error
from .rs485 import RS485, RS485Mode

__all__ = ["CheckResult", "judge", "measure", "PATTERN"]

log = logging.getLogger(__name__)

#: alternating bits, then a distinct last byte: a lost or altered byte shows
PATTERN = bytes([0x55, 0xAA] * 15 + [0x0F, 0xF0])


@dataclass(frozen=True)
class CheckResult:
    """What the direction check measured and what it makes of it."""

    device: str
    mode: str                    #: the mode the port ran in
    rounds: int
    echoed: int                  #: rounds whose whole pattern came back
    collisions: int              #: echoed bytes that differ from the bytes sent
    margins_us: Tuple[int, ...]  #: release minus last echo, per echoed round
    recommend: str               #: kernel, soft, gpio or none
    warnings: Tuple[str, ...] = field(default_factory=tuple)

    @property
    def release_us(self) -> Optional[int]:
        """The median margin (µs), None without echo."""
        return int(statistics.median(self.margins_us)) if self.margins_us else None


def judge(device: str, mode: RS485Mode, rounds: int, echoed: int, collisions: int,
          margins_us: Tuple[int, ...], kernel_rs485: bool) -> CheckResult:
    """The verdict from what the measurement saw: the rounds run, those
    whose whole pattern came back, the bytes that came back different, and
    per echoed round the release minus the last echo (µs)."""
    if not isinstance(device, str):
        raise InvalidTypeError(f"device must be a str, not {type(device).__name__}")
    if not isinstance(mode, RS485Mode):
        raise InvalidTypeError(f"mode must be an RS485Mode, not {type(mode).__name__}")
    rounds, echoed, collisions = (check_int(v, what, 0, U32) for v, what in
                                  ((rounds, "rounds"), (echoed, "echoed"),
                                   (collisions, "collisions")))
    if not isinstance(margins_us, (tuple, list)):
        raise InvalidTypeError(f"margins_us must be a tuple of ints, not "
                               f"{type(margins_us).__name__}")
    margins = [check_int(m, "margins_us item", -U32, U32) for m in margins_us]
    check_bool(kernel_rs485, "kernel_rs485")
    warnings = []
    if not margins:
        warnings.append("no echo: the transceiver does not hear itself (receiver off while "
                        "sending?), so the release cannot be measured")
    elif min(margins) < 0:
        warnings.append(f"the port released the line up to {-min(margins)} us before its last "
                        "byte came back: tcdrain does not cover this adapter; use kernel "
                        "RS-485, an auto-direction transceiver, or a delay after sending of "
                        f"at least {-min(margins)} us")
    if collisions:
        warnings.append(f"{collisions} echoed bytes differ from the bytes sent (a collision or "
                        "a noisy line)")
    if kernel_rs485:
        recommend = "kernel"
    elif mode in (RS485Mode.SOFT_RTS, RS485Mode.GPIO):
        recommend = "soft" if mode == RS485Mode.SOFT_RTS else "gpio"
    else:
        recommend = "none"
    return CheckResult(device, mode.name.lower(), rounds, echoed, collisions, tuple(margins),
                       recommend, tuple(warnings))


def measure(path: str, baudrate: int, rs485: RS485, *, rounds: int = 5,
            timeout: float = 1.0, kernel_rs485: bool = False) -> CheckResult:
    """Send :data:`PATTERN` ``rounds`` times on ``path`` and time each
    release against the last echoed byte: ``fap_port_check_direction``
    (the measurement is C's, for the guests' checks too; the verdict is
    :func:`judge`'s)."""
    from ._native import ffi, lib

    path = check_path(path, "path")
    baudrate = check_baud(baudrate)
    if not isinstance(rs485, RS485):
        raise InvalidTypeError(f"rs485 must be an RS485, not {type(rs485).__name__}")
    # out-of-range counts are clamped (the CLI's --rounds relies on it); wrong types refused
    rounds = min(max(1, check_int(rounds, "rounds", -U32, U32)),
                 int(lib.FAP_PORT_CHECK_MAX_ROUNDS))
    wait_ms = int(check_seconds(timeout, "timeout") * 1000)
    check_bool(kernel_rs485, "kernel_rs485")
    out = ffi.new("fap_port_check *")
    line = dataclasses.replace(rs485, echo_suppression=False)
    with Port(path, baudrate, line) as port:
        r = port._call(lib.fap_port_check_direction, PATTERN, len(PATTERN), rounds,
                       wait_ms, out)
        if r < 0:
            raise port_error(r, "direction check", path)
        mode = port.mode
    margins = tuple(int(out.margin_ns[i]) // 1000 for i in range(out.echoed))
    log.debug("direction check %s: %d rounds, %d echoed, margins %s us", path, out.rounds,
              out.echoed, margins)
    return judge(path, mode, int(out.rounds), int(out.echoed), int(out.collisions), margins,
                 kernel_rs485)
