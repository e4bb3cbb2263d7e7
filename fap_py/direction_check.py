"""Self-verifying direction control: when does the port release the line,
against the last byte the transceiver echoed back?

With a 2-wire transceiver whose receiver stays on while sending (RX during
TX), every byte sent comes back. The check sends a test pattern several
times through :class:`fap_py.port.Port` (echo suppression off), reads the
echo on a second thread, and compares the moment the write returned (soft
RTS / GPIO: after the line was released; other modes: after ``tcdrain``)
with the moment the last echoed byte was read, both on the C layer's
``CLOCK_MONOTONIC``. A negative margin means the port let go of the line
before its own last byte came back: ``tcdrain`` returned early (a USB
adapter's FIFO, a pty) and a soft-RTS transceiver would cut the frame.

:func:`judge` is pure (times in, verdict out); :func:`measure` does the I/O.
Times read in userspace include the receive path's latency (FIFO timeout,
USB polling): the margin is a bound, not the pin's edge.
"""
from __future__ import annotations

import dataclasses
import errno
import logging
import statistics
import threading
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

from .errors import FapTimeoutError, PortError
from .port import Port, now_ns
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


def judge(device: str, mode: RS485Mode, rounds: int, sent: bytes,
          results: List[Tuple[int, Optional[int], bytes]], kernel_rs485: bool) -> CheckResult:
    """The verdict from per-round (release ns, last echo ns or None, echo bytes)."""
    margins, collisions, echoed = [], 0, 0
    for release, last, echo in results:
        collisions += sum(a != b for a, b in zip(echo, sent)) + max(0, len(echo) - len(sent))
        if last is not None and len(echo) >= len(sent):
            echoed += 1
            margins.append((release - last) // 1000)
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


def _read_echo(port: Port, want: int, deadline: int, out: bytearray, last: List[int]) -> None:
    """Read up to ``want`` bytes into ``out`` until ``deadline`` (ns);
    ``last`` gets the time the latest chunk was read."""
    while len(out) < want and now_ns() < deadline:
        got = port.read(want - len(out), deadline_ns=deadline)
        if got:
            out.extend(got)
            last[:] = [now_ns()]


def measure(path: str, baudrate: int, rs485: RS485, *, rounds: int = 5,
            timeout: float = 1.0, kernel_rs485: bool = False) -> CheckResult:
    """Send :data:`PATTERN` ``rounds`` times on ``path`` and time each
    release against the last echoed byte (see the module doc)."""
    line = dataclasses.replace(rs485, echo_suppression=False)
    results: List[Tuple[int, Optional[int], bytes]] = []
    with Port(path, baudrate, line) as port:
        for _ in range(rounds):
            port.read(4096)   # what was there before is not our echo
            echo = bytearray()
            last: List[int] = []
            t = threading.Thread(target=_read_echo, daemon=True, args=(
                port, len(PATTERN), now_ns() + int(timeout * 1e9), echo, last))
            t.start()
            try:
                port.write(PATTERN)
            except PortError as exc:
                if exc.errno == errno.ETIMEDOUT:
                    raise FapTimeoutError(f"{path}: the test pattern was not sent") from exc
                raise
            release = now_ns()
            t.join(timeout + 1)
            results.append((release, last[0] if last else None, bytes(echo)))
            log.debug("round: release %d, last echo %s, %d bytes", release, last, len(echo))
        mode = port.mode
    return judge(path, mode, rounds, PATTERN, results, kernel_rs485)
