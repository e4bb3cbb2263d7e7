"""The project's benchmarks (``python -m bench``; bench/README.md).

Not part of the installed package: run from the checkout. The harness's
modules import only each other in one direction (``__main__`` -> runner
pieces -> ``stats``/``kinds``/``targets``), never ``tests/`` nor the CLI's
private modules, so ``python -m bench`` needs only ``pip install '.[bench]'``
(tests/python/test_bench_imports.py checks it).
"""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def use_installed_fap_py() -> None:
    """Take the checkout off ``sys.path``: its fap_py/ has no compiled
    ``_native``, so the bench (and its children) use the installed fap_py.
    ``bench`` itself stays importable: it is imported already."""
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT]


def results_home() -> Path:
    """Where runs go by default: ``$XDG_CACHE_HOME/fap-bench`` (else
    ``~/.cache/fap-bench``), outside the source tree; ``--out`` overrides."""
    import os

    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "fap-bench"
