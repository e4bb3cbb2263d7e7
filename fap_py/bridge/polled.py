"""What the request/reply masters share (exec async, mikroC, and a plug-in like them):
the keys ``nodes`` and ``poll_data`` (each listed node is sent ``poll_data`` every
``poll_interval``; its reply is published on rx) and a tx that is one request and its
reply, or a broadcast without one."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple

from .. import _protocols
from ..errors import FapError
from ._schema import check_plugin_args, hex_bytes, id_list, pop
from .buses import BusAdapter, TxError, hex_field

__all__ = ["PolledOptions", "polled_options", "PolledAdapter"]


@dataclass(frozen=True)
class PolledOptions:
    """The keys of a polling request/reply master."""

    nodes: Tuple[int, ...] = ()        #: nodes polled with ``poll_data``
    poll_data: Optional[bytes] = None  #: the request sent to each of ``nodes`` (None: no polling)


def polled_options(t: Dict[str, Any], where: str, role: str, proto: _protocols.Protocol) -> PolledOptions:
    """Take and check ``nodes`` (in the protocol's node range) and ``poll_data`` (hex)."""
    check_plugin_args(t, where, role, proto)
    nodes = id_list(pop(t, "nodes", list, where, []), proto.node_min, proto.node_max, f"{where}.nodes")
    return PolledOptions(nodes, hex_bytes(t, "poll_data", where))


class PolledAdapter(BusAdapter):
    """A master that polls ``nodes``; a subclass gives ``_request`` and ``_broadcast``."""

    def _request(self, node: int, data: bytes) -> bytes:
        """One request to ``node`` and its reply's data (raises the engine's FapError)."""
        raise NotImplementedError

    def _broadcast(self, data: bytes) -> None:
        """``data`` to every node (no reply)."""
        raise NotImplementedError

    def configured_nodes(self) -> Tuple[int, ...]:
        nodes: Tuple[int, ...] = self.cfg.options.nodes
        return nodes

    def _polls(self) -> bool:
        o = self.cfg.options
        return o.poll_data is not None and bool(o.nodes)

    def poll(self) -> None:
        o = self.cfg.options
        for node in o.nodes:
            try:
                reply = self._timed(node, self._request, node, o.poll_data)
            except FapError as exc:
                self._polled(node, None, exc)
            else:
                self._polled(node, {"data": reply.hex()}, None)

    def _check_tx(self, node: int, req: Dict[str, Any]) -> None:
        self._data(req)

    def _data(self, req: Dict[str, Any]) -> bytes:
        op = req.get("op", "send")
        if op != "send":
            raise TxError(f"op {str(op)[:40]!r}: a {self.proto.name} bus only sends")
        return hex_field(req)

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        data = self._data(req)
        if node == self.proto.broadcast:
            self._broadcast(data)
            return {"data": ""}
        reply = self._timed(node, self._request, node, data)
        self.sink.state(self.cfg.name, node, True)
        return {"data": reply.hex()}
