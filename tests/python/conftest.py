"""Hooks of every Python test: a test marked ``direct_only(reason)`` gets no run through
the daemon (the fixtures named ``net`` of the exec async and G485 tests run each test on
the port itself and through ``fap serve``: ``fapd://``)."""
from __future__ import annotations

from typing import List

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: List[pytest.Item]) -> None:
    """No daemon run for a test marked ``direct_only`` (it needs the port's own master)."""
    drop = [it for it in items if it.get_closest_marker("direct_only")
            and getattr(it, "callspec", None) is not None and it.callspec.params.get("net") == "daemon"]
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = [it for it in items if it not in drop]
