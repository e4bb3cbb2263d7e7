"""Registers the toy protocol (tests/python/toy/toyproto) for the tests in this folder.

The toy's plug-ins (monitor, bridge, soak, CLI) live in the toyproto package exactly where a
built-in protocol's live in fap_py; registering its table row is the one edit a fifth
protocol makes to fap_py._protocols.
"""

import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from fap_py import _protocols  # noqa: E402

TOY = _protocols.Protocol("toy", "toy protocol (tests only)", 250, "toyproto.binding", package="toyproto")


@pytest.fixture(autouse=True)
def toy_protocol():
    """The toy row in the table for the test's duration (and its folder on sys.path, so a
    child process started with PYTHONPATH=toy_pythonpath() finds it too)."""
    _protocols.register(TOY)
    try:
        yield TOY
    finally:
        _protocols.unregister("toy")


def toy_pythonpath() -> str:
    """PYTHONPATH for a child process (soak children, the CLI run as a program) that must see
    the toy: the child registers it from FAP_EXTRA_PROTOCOLS (see docs/architecture.md)."""
    return os.pathsep.join([HERE] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])
