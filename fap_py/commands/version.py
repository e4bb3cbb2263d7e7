"""``fap version``: versions of the package and of the C core it loaded."""
from __future__ import annotations

import argparse

from ._options import add_command, add_output_options, emit


def register(sub: argparse._SubParsersAction) -> None:
    p = add_command(sub, "version", help="print the fap_py and libfap versions",
                    example="fap version --json")
    add_output_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import fap_py

    emit(args, {"event": "version", "fap_py": fap_py.__version__, "libfap": fap_py.native_version()},
         f"fap_py {fap_py.__version__}, libfap core {fap_py.native_version()}")
    return 0
