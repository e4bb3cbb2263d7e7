"""``fap version``: versions of the package and of the C core it loaded."""
from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("version", help="print the fap_py and libfap versions")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import fap_py

    print(f"fap_py {fap_py.__version__}, libfap core {fap_py.native_version()}")
    return 0
