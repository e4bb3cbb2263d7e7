"""``fap doctor``'s library: why a serial port does not work, with evidence and fix.

The public API is this module and nothing else; every argument is checked and a
bad one raises the package's own errors (:mod:`fap_py.errors`):

- :func:`run`: every check on a machine (``root``: ``/`` is this one), the
  :class:`Finding` list, worst first;
- :class:`Finding` (id, severity, cause, evidence, fix), :data:`SEVERITIES`,
  :data:`EXIT_BY_SEVERITY`, :func:`worst` and :func:`exit_code` (``fap doctor``'s
  exit code of a report);
- :func:`listen`: ``--listen``, the bus on a port identified by the monitor's
  decoders, never transmitting;
- :func:`write_bundle`: ``--bundle``, the evidence as a tar.gz with secrets masked.

The machinery behind it is private and may change: ``_context`` (the analysed
machine, every path resolved beneath the root, bounded reads), ``_registry`` (the
checks, found by module in ``_checks``: one file per check or small group, each
with a stable id, docs/doctor.md), ``_listen``, ``_bundle`` and ``_finding``.
"""
from __future__ import annotations

import os
from typing import Any, Iterable, List, Optional

from .._validate import check_baud, check_path, check_seconds
from ..errors import FileError, InvalidTypeError, InvalidValueError
from ._finding import EXIT_BY_SEVERITY, SEVERITIES, Finding

__all__ = ["EXIT_BY_SEVERITY", "LISTEN_MAX_S", "SEVERITIES", "Finding", "check_ids", "exit_code",
           "listen", "run", "worst", "write_bundle"]

#: the longest :func:`listen` (and ``fap doctor --listen``), seconds
LISTEN_MAX_S = 3600.0


def _text(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise InvalidTypeError(f"{what} must be a str, not {type(value).__name__}")
    if not value or "\0" in value:
        raise InvalidValueError(f"{what} must be a non-empty str without NUL bytes, not {value!r}")
    return value


def _findings(findings: Any) -> List[Finding]:
    if isinstance(findings, (str, bytes, bytearray, memoryview)):
        raise InvalidTypeError(f"findings must be an iterable of Finding, not {type(findings).__name__}")
    try:
        out = list(findings)
    except TypeError:
        raise InvalidTypeError(f"findings must be an iterable of Finding, not "
                               f"{type(findings).__name__}") from None
    for f in out:
        if not isinstance(f, Finding):
            raise InvalidTypeError(f"findings must hold Finding objects, not {type(f).__name__}")
    return out


def _make_context(root: Any, port: Any, user: Any, kernel_log: Any, baud: Any) -> Any:
    from ._context import Context

    root = check_path(root, "root")
    if not os.path.isdir(root):
        raise InvalidValueError(f"root {root!r} is not a directory")
    if port is not None:
        port = check_path(port, "port")
    if user is not None:
        user = _text(user, "user")
    if kernel_log is not None:
        kernel_log = check_path(kernel_log, "kernel_log")
    if baud is not None:
        baud = check_baud(baud, "baud")
    return Context(root=root, port=port, user=user, kernel_log=kernel_log, baud=baud)


def check_ids() -> List[str]:
    """The stable id of every check, in the order they run (docs/doctor.md)."""
    from ._registry import all_checks
    return [c.id for c in all_checks()]


def _only(only: Any) -> Optional[List[str]]:
    if only is None:
        return None
    if isinstance(only, (str, bytes)):
        raise InvalidTypeError("only must be an iterable of check ids, not a single "
                               f"{type(only).__name__}")
    try:
        ids = list(only)
    except TypeError:
        raise InvalidTypeError(f"only must be an iterable of check ids, not "
                               f"{type(only).__name__}") from None
    known = check_ids()
    for i in ids:
        if not isinstance(i, str):
            raise InvalidTypeError(f"only must hold check ids (str), not {type(i).__name__}")
        if i not in known:
            raise InvalidValueError(f"unknown doctor check id {i!r}; known: {', '.join(known)}")
    return ids


def run(root: str = "/", port: Optional[str] = None, user: Optional[str] = None, *,
        kernel_log: Optional[str] = None, baud: Optional[int] = None,
        only: Optional[Iterable[str]] = None) -> List[Finding]:
    """Run the checks (``only``: these ids, :func:`check_ids`) on the machine at
    ``root`` for ``port`` (a bare name is a /dev name) and ``user``; the findings,
    worst first. Nothing is changed and, on a copied tree, nothing is opened."""
    from ._finding import ordered
    from ._registry import run as run_checks

    ctx = _make_context(root, port, user, kernel_log, baud)
    return ordered(run_checks(ctx, _only(only)))


def worst(findings: Iterable[Finding]) -> str:
    """The worst severity among ``findings`` (``"ok"`` when there are none)."""
    from ._finding import worst as worst_of
    return worst_of(_findings(findings))


def exit_code(findings: Iterable[Finding]) -> int:
    """``fap doctor``'s exit code for ``findings``: :data:`EXIT_BY_SEVERITY` of the worst."""
    return EXIT_BY_SEVERITY[worst(findings)]


def listen(port: str, seconds: float) -> Finding:
    """Listen on ``port`` (this machine's, never transmitting) for ``seconds``
    (0 < seconds <= :data:`LISTEN_MAX_S`) and name the protocol and baud on the bus:
    a ``listen.bus`` finding (an ``error`` one when the port cannot be opened)."""
    from ._listen import listen as listen_on

    path = check_path(port, "port")
    s = check_seconds(seconds, "seconds", lo=0.0, lo_open=True, hi=LISTEN_MAX_S)
    return listen_on(path, s)


def write_bundle(path: str, root: str = "/", port: Optional[str] = None,
                 user: Optional[str] = None, *, kernel_log: Optional[str] = None,
                 baud: Optional[int] = None) -> int:
    """Run the checks as :func:`run` does and write their evidence and report to the
    tar.gz ``path`` (secrets masked); the number of evidence files. FileError when
    ``path`` cannot be written."""
    from ._bundle import write
    from ._finding import ordered
    from ._registry import run as run_checks

    path = check_path(path, "path")
    if os.path.isdir(path):
        raise FileError(21, "bundle: is a directory", path)
    ctx = _make_context(root, port, user, kernel_log, baud)
    return write(path, ctx, ordered(run_checks(ctx)))
