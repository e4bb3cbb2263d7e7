"""The performance targets of issue 24, judged from one run's results.

Every bench part that measures a target returns ``Target`` rows; the runner prints
them as one met/missed table (``table.md``, ``results.json``). A missed target
carries the note that says why (the profile) and what the floor of that cost is.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Dict, List, Optional


@dataclass(frozen=True)
class Target:
    """One target: what was asked, what this run measured, and the verdict."""

    name: str                 #: short id, e.g. "cpu-fap-poll-115200"
    goal: str                 #: the target in words, e.g. "CPU/exchange <= 0.5x libmodbus"
    value: Optional[float]    #: measured (None: not measured in this run)
    limit: float              #: the bound the value is compared with
    higher_is_better: bool    #: True: met when value >= limit; False: met when value <= limit
    unit: str = ""
    note: str = ""            #: why missed / how measured / the floor of the cost

    @property
    def met(self) -> Optional[bool]:
        """True/False, or None when the value was not measured."""
        if self.value is None:
            return None
        return self.value >= self.limit if self.higher_is_better else self.value <= self.limit

    def as_dict(self) -> Dict[str, Any]:
        d = asdict(self)
        d["met"] = self.met
        return d


def table(targets: List[Target]) -> str:
    """A Markdown table: target, goal, value, verdict, note."""
    rows = ["| target | goal | measured | verdict | note |", "|---|---|---|---|---|"]
    for t in targets:
        v = "not measured" if t.value is None else f"{t.value:.3g}{(' ' + t.unit) if t.unit else ''}"
        verdict = {True: "met", False: "missed", None: "not measured"}[t.met]
        rows.append(f"| {t.name} | {t.goal} | {v} | {verdict} | {t.note} |")
    return "\n".join(rows) + "\n"
