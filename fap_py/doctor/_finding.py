"""A doctor finding: what one check saw, why it matters and the exact fix."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Dict, Iterable, List, Optional

from ..errors import InvalidTypeError, InvalidValueError

#: severities, mildest first; ``rank`` orders a report worst first
SEVERITIES = ("ok", "info", "warning", "error")

#: exit codes of ``fap doctor`` by the worst severity found (usage errors stay 2,
#: interrupted 130: docs/doctor.md)
EXIT_BY_SEVERITY: Dict[str, int] = {"ok": 0, "info": 0, "warning": 4, "error": 5}


def rank(severity: str) -> int:
    """0 (ok) .. 3 (error)."""
    return SEVERITIES.index(severity)


@dataclass(frozen=True)
class Finding:
    """One result of one check.

    ``id`` is the check's stable id (docs/doctor.md); ``evidence`` names what was
    read (a file and line, a log line, a pid and command, a sysfs value);
    ``cause`` is one line; ``fix`` the exact command or snippet (empty when
    nothing is to be done). The doctor never applies a fix."""

    id: str
    severity: str
    cause: str
    evidence: List[str] = field(default_factory=list)
    fix: str = ""
    port: Optional[str] = None
    #: structured results of a finding that has them (``--listen``: protocol, baud ...)
    detail: Optional[Dict[str, Any]] = None

    def __post_init__(self) -> None:
        for what in ("id", "severity", "cause", "fix"):
            if not isinstance(getattr(self, what), str):
                raise InvalidTypeError(f"Finding {what} must be a str, not "
                                       f"{type(getattr(self, what)).__name__}")
        if not self.id:
            raise InvalidValueError("Finding id must be a check id, not empty")
        if self.severity not in SEVERITIES:
            raise InvalidValueError(f"severity must be one of {SEVERITIES}, not {self.severity!r}")
        if isinstance(self.evidence, (str, bytes)) or not isinstance(self.evidence, (list, tuple)):
            raise InvalidTypeError(f"Finding evidence must be a list of str, not "
                                   f"{type(self.evidence).__name__}")
        if not all(isinstance(e, str) for e in self.evidence):
            raise InvalidTypeError("Finding evidence must hold str lines")
        object.__setattr__(self, "evidence", list(self.evidence))
        if self.port is not None and not isinstance(self.port, str):
            raise InvalidTypeError(f"Finding port must be a str or None, not "
                                   f"{type(self.port).__name__}")
        if self.detail is not None and not isinstance(self.detail, dict):
            raise InvalidTypeError(f"Finding detail must be a dict or None, not "
                                   f"{type(self.detail).__name__}")

    def as_event(self) -> Dict[str, Any]:
        """The ``--json`` object: an ``event`` key like the other commands' rows."""
        row: Dict[str, Any] = {"event": "finding"}
        row.update(asdict(self))
        if row["detail"] is None:
            del row["detail"]
        return row


def worst(findings: Iterable[Finding]) -> str:
    """The worst severity among ``findings`` (ok when there are none)."""
    return max((f.severity for f in findings), key=rank, default="ok")


def ordered(findings: Iterable[Finding]) -> List[Finding]:
    """Worst first; within a severity, the checks' order (stable)."""
    return sorted(findings, key=lambda f: -rank(f.severity))


def exit_code(findings: Iterable[Finding]) -> int:
    return EXIT_BY_SEVERITY[worst(findings)]
