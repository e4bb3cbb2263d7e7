"""The node range of exec async comes from C (include/exec_async.h), never re-typed."""
from __future__ import annotations

import pytest

from fap_py import execasync
from fap_py._native import lib
from fap_py.execasync import ExecValueError


def test_node_range_is_the_c_headers() -> None:
    assert (execasync.NODE_MIN, execasync.NODE_MAX) == (lib.EXEC_ASYNC_NODE_MIN, lib.EXEC_ASYNC_NODE_MAX)
    assert (execasync.NODE_MIN, execasync.NODE_MAX) == (1, 254)
    assert execasync.NODE_MAX + 1 == execasync.BROADCAST


@pytest.mark.parametrize("node", [lib.EXEC_ASYNC_NODE_MIN - 1, lib.EXEC_ASYNC_NODE_MAX + 1])
def test_slave_outside_the_range_is_refused(node: int) -> None:
    with pytest.raises(ExecValueError):
        execasync.Slave("/dev/null", node=node, handler=lambda request: b"")
