"""Ctrl-C ends an engine's network open at once (issue 32 items 10-11, "every
Ctrl-C ends within 0.5 s whatever the server does").

``fap.Master``, ``execasync.Master`` / ``Slave`` and ``mikroc.Master`` / ``Slave`` open
with one C call; on the calling thread that call held off Ctrl-C until it
returned (against a Telnet flood: 2 x option_ms, here 10 minutes). Now the
open runs in a helper thread and KeyboardInterrupt writes the open's cancel
fd (``fapx_options.cancel_fd``, ``exec*Options.cancel_fd``, the port's own
for mikroC): the open ends at once and KeyboardInterrupt goes on.

Each child opens ``rfc2217://127.0.0.1:PORT`` on a flooding server
(test_network_hostile.Hostile); it is signalled once the server has its
connection (no sleep).
"""
from __future__ import annotations

import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from test_network_hostile import Hostile, _interrupt_child

#: the issue's 0.5 s, with room for a loaded 2-core machine
BOUND = 1.0

_OPENS = {
    "fap": "from fap_py.fap import Master\nMaster(url)",
    "exec_master": "from fap_py.execasync import Master\nMaster(url)",
    "exec_slave": "from fap_py.execasync import Slave\nSlave(url, node=1, handler=lambda n, d: d)",
    "mikroc": "from fap_py.mikroc import Master\nMaster(url)",
    "mikroc_slave": "from fap_py.mikroc import Slave\nSlave(url, address=1)",
}

_CHILD = r"""
import sys
url = sys.argv[1]
try:
{open}
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
print("opened", flush=True)
"""


def _child(api: str) -> str:
    body = "\n".join("    " + line for line in _OPENS[api].splitlines())
    return _CHILD.format(open=body)


@pytest.mark.parametrize("kind", ["nop", "sb"])
@pytest.mark.parametrize("api", sorted(_OPENS))
def test_ctrl_c_ends_an_engine_open(api: str, kind: str) -> None:
    """The open would wait option_ms = 10 minutes; Ctrl-C ends it at once."""
    with Hostile(kind) as srv:
        took = _interrupt_child(_child(api), srv.url(query="?option_ms=600000"), srv.accepted)
    assert took < BOUND, (api, kind, took)
