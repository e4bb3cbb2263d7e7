"""A fourth bridge output, out of tree: it records what the bridge tells it
(test_bridge_outputs.py plugs it in with FAP_BRIDGE_OUTPUTS, no edit to fap_py)."""
from __future__ import annotations

import threading
from typing import Any, Iterable, List, Optional, Tuple

from fap_py.bridge.outputs import BridgeView, NodeEvent, NodeView, OutputBase

TOPIC = "toy/cmd"


class ToyOutput(OutputBase):
    name = "toy"
    fail_start = False   # set by a test: start() raises (the bridge must not start)
    made: List["ToyOutput"] = []

    def __init__(self, config: Any) -> None:
        self.config = config
        self.calls: List[Tuple[Any, ...]] = []
        self.ctx: Optional[BridgeView] = None
        self.cond = threading.Condition()
        ToyOutput.made.append(self)

    def _note(self, *call: Any) -> None:
        with self.cond:
            self.calls.append(call)
            self.cond.notify_all()

    def wait(self, pred: Any, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: any(pred(c) for c in self.calls), timeout)

    def subscriptions(self) -> Iterable[str]:
        return (TOPIC,)

    def start(self, ctx: BridgeView) -> None:
        if self.fail_start:
            raise OSError("toy output: cannot start")
        self.ctx = ctx
        self._note("start", ctx)

    def on_connect(self, link: Any) -> None:
        self._note("connect", link.connected)

    def on_node_event(self, view: NodeView, event: NodeEvent) -> None:
        self._note("event", event.kind, event.bus, event.node, event.active,
                   None if event.fields is None else dict(event.fields), view.rx, view)

    def on_message(self, topic: str, payload: bytes) -> None:
        self._note("message", topic, payload)

    def on_tick(self) -> None:
        self._note("tick")

    def stop(self) -> None:
        self._note("stop")
