"""``fap doctor``'s library: why a serial port does not work, with evidence and fix.

- :mod:`.finding`: :class:`Finding` (id, severity, evidence, cause, fix) and the
  exit code of the worst severity;
- :mod:`.context`: the analysed machine (``--root``), one helper resolving every
  path beneath it, bounded reads;
- :mod:`.registry`: the checks, found by module in :mod:`.checks` (one file per
  check or small group, each with a stable id: docs/doctor.md);
- :mod:`.listen`: ``--listen``, the bus identified by the monitor's decoders;
- :mod:`.bundle`: ``--bundle``, the evidence as a tar with secrets masked.
"""
from __future__ import annotations

from .context import Context
from .finding import EXIT_BY_SEVERITY, SEVERITIES, Finding, exit_code, ordered, worst
from .registry import all_checks, check, run

__all__ = ["EXIT_BY_SEVERITY", "SEVERITIES", "Context", "Finding", "all_checks", "check",
           "exit_code", "ordered", "run", "worst"]
