"""Child of test_ctrl_c_storm_keeps_the_node_consistent: fap_py calls under a
storm of SIGINTs; the handler raises KeyboardInterrupt only while armed, i.e.
somewhere inside the node calls below. Prints the node's bookkeeping, then
closes the node (which must not hang) and prints ``closed``."""
from __future__ import annotations

import signal
import sys
from typing import Any

from fap_py import FapTimeoutError, Slave

state = {"armed": False, "hits": 0}


def handler(signum: int, frame: Any) -> None:
    if state["armed"]:
        state["armed"] = False
        state["hits"] += 1
        raise KeyboardInterrupt


def main() -> int:
    s = Slave(sys.argv[1], id=1, tx_queue=100000)
    signal.signal(signal.SIGINT, handler)
    print("ready", flush=True)
    for _ in range(int(sys.argv[2])):
        try:
            state["armed"] = True
            s.recv_nowait()
            assert s.stats.frames_rx >= 0
            s.send(b"x", 0)
            try:
                s.recv(timeout=0.001)
            except FapTimeoutError:
                pass
            state["armed"] = False
        except KeyboardInterrupt:
            pass
    state["armed"] = False
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the storm's tail must not kill us
    print(f"users={s._users} hits={state['hits']}", flush=True)
    s.close()
    print("closed", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
