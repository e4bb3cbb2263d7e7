"""Supply trouble the kernel logged (``power.undervoltage``): a Raspberry Pi
under-voltage drops its USB adapters."""
from __future__ import annotations

import re
from typing import Iterator

from .._context import Context
from .._finding import Finding
from .._registry import check

_UV_RE = re.compile(r"under-?\s?voltage detected", re.IGNORECASE)


@check("power.undervoltage", "the kernel logged no under-voltage")
def undervoltage(ctx: Context) -> Iterator[Finding]:
    log = ctx.kernel_log()
    if not log:
        yield Finding("power.undervoltage", "info", "no kernel log read: not checked",
                      ["no /var/log/kern.log or dmesg file"], "--kernel-log FILE (`dmesg > FILE`)")
        return
    hits = [(n, ln) for n, ln in enumerate(log, 1) if _UV_RE.search(ln)]
    if not hits:
        yield Finding("power.undervoltage", "ok", "no under-voltage in the kernel log",
                      [f"{ctx.kernel_log_source}: {len(log)} lines"])
        return
    usb = sum(1 for ln in log if "USB disconnect" in ln)
    yield Finding("power.undervoltage", "error",
                  f"the supply sagged ({len(hits)} under-voltage events): USB adapters reset and "
                  "their ttys vanish", [f"{ctx.kernel_log_source}:{n}: {ln.strip()[:200]}"
                                        for n, ln in hits[:3]]
                  + ([f"{usb} USB disconnects in the log"] if usb else []),
                  "a supply that holds 5.1 V under load (Pi 4: 3 A, Pi 5: 5 A) or a powered USB "
                  "hub for the adapters; `vcgencmd get_throttled` shows the state")
