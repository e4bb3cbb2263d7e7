"""Registers the toy protocol (tests/python/toy/toyproto) for the tests in this folder.

The toy's plug-ins (monitor, bridge, soak, CLI) live in the toyproto package exactly where a
built-in protocol's live in fap_py; its table row (toyproto/table.py) is the one edit a fifth
protocol makes to fap_py._protocols.
"""

import os
import sys

import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from toyproto.table import TOY  # noqa: E402

from fap_py import _protocols  # noqa: E402


@pytest.fixture(autouse=True)
def toy_protocol():
    """The toy row in the table for the test's duration."""
    _protocols.register(TOY)
    try:
        yield TOY
    finally:
        _protocols.unregister("toy")


@pytest.fixture
def toy_env():
    """Environment for a child process (a soak child, the CLI run as a program) that must
    see the toy: its folder on PYTHONPATH and its row in FAP_EXTRA_PROTOCOLS."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([HERE] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env[_protocols.ENV_EXTRA] = "toyproto.table:TOY"
    return env
