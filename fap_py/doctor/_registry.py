"""The checks' registry: every module of :mod:`fap_py.doctor._checks` registers its
checks with :func:`check`; :func:`all_checks` imports them all (a new file there
needs no edit elsewhere) and :func:`run` runs them, a failing check turned into
an ``info`` finding that says it was skipped (never a traceback)."""
from __future__ import annotations

import importlib
import logging
import pkgutil
from dataclasses import dataclass
from typing import Callable, Dict, Iterable, List, Optional

from ..errors import InvalidValueError
from ._context import Context
from ._finding import Finding

log = logging.getLogger(__name__)

CheckFn = Callable[[Context], Iterable[Finding]]


@dataclass(frozen=True)
class Check:
    id: str
    title: str
    fn: CheckFn
    order: int


_CHECKS: Dict[str, Check] = {}


def check(id: str, title: str) -> Callable[[CheckFn], CheckFn]:
    """Register ``fn(ctx) -> findings`` under the stable ``id``."""
    def deco(fn: CheckFn) -> CheckFn:
        if id in _CHECKS and _CHECKS[id].fn is not fn:
            raise InvalidValueError(f"doctor check id {id!r} registered twice")
        _CHECKS[id] = Check(id, title, fn, len(_CHECKS))
        return fn
    return deco


def all_checks() -> List[Check]:
    """Every check, in registration order (the modules imported by name order)."""
    from . import _checks
    for info in pkgutil.iter_modules(_checks.__path__):
        if not info.name.startswith("_"):
            importlib.import_module(f"{_checks.__name__}.{info.name}")
    return sorted(_CHECKS.values(), key=lambda c: c.order)


def run(ctx: Context, only: Optional[Iterable[str]] = None) -> List[Finding]:
    """Every check's findings in check order (``only``: these ids)."""
    wanted = set(only) if only is not None else None
    out: List[Finding] = []
    for c in all_checks():
        if wanted is not None and c.id not in wanted:
            continue
        try:
            out.extend(c.fn(ctx))
        except Exception as exc:   # a hostile tree must not end the report
            log.debug("check %s failed", c.id, exc_info=True)
            out.append(Finding(c.id, "info", f"check skipped: {type(exc).__name__}: {exc}"))
    return out
