"""Exec async nodes of ``fap sim``: echo, a reply table or a generator's value, in Python over
the port layer with the package's exec async codec (``fap_py.execasync.encode`` / ``Decoder``)."""
from __future__ import annotations

from typing import Any, Dict, List, Optional

from ... import execasync
from .._faults import REPLY_KINDS
from .._responder import CodecFramer, Request, flip_to, garbage_without
from .._schema import Path, Problem
from . import _reply

NAME = "exec"
ADDRESS_MIN, ADDRESS_MAX = execasync.NODE_MIN, execasync.NODE_MAX
FAULTS = REPLY_KINDS
NODE_PROPERTIES: Dict[str, Any] = dict(_reply.REPLY_PROPERTIES)


def check_node(node: Dict[str, Any], where: Path) -> List[Problem]:
    return _reply.check(node, where, execasync.MAX_DATA)


def request_size(frame: Any) -> int:
    """The request's bytes on the wire (a direction-request fault draws each)."""
    return len(execasync.encode(frame.node, frame.data, frame.seq))


class _Decoder:
    idle_timeout = 0.2

    def __init__(self) -> None:
        self._dec = execasync.Decoder()

    def feed(self, data: bytes) -> List[Request]:
        out = []
        for f in self._dec.feed(data):
            if f.ok and f.node != execasync.BROADCAST:
                out.append(Request(f.node, f))
            elif f.ok:
                out.append(Request(None, f))
        return out

    def idle(self) -> List[Request]:
        return []


def request_decoder(baud: int) -> _Decoder:
    return _Decoder()


class Node:
    """One exec async node. A retry (the same non-zero sequence number again) gets the last
    reply again without running the behaviour a second time, as the C slave does."""

    def __init__(self, address: int, cfg: Dict[str, Any], seed: int) -> None:
        self.address = address
        self.behaviour = _reply.Behaviour(cfg, seed)
        self._last: Optional[tuple] = None

    def hear(self, frame: Any) -> None:   # a broadcast: executed, never answered
        self.behaviour.reply(frame.data, 0.0)

    def answer(self, frame: execasync.Frame, t: float) -> Optional[bytes]:
        if frame.seq and self._last is not None and self._last[0] == frame.seq:
            return self._last[1]
        data = self.behaviour.reply(frame.data, t)
        out = None if data is None else execasync.encode(self.address, data, frame.seq)
        self._last = (frame.seq, out)
        return out


def make_node(address: int, cfg: Dict[str, Any], seed: int) -> Node:
    return Node(address, cfg, seed)


def _bad(frame: bytes) -> bool:
    got = execasync.Decoder().feed(frame)
    return len(got) == 1 and got[0].status is execasync.Status.BAD_CRC


def bad_check(frame: bytes) -> bytes:
    return flip_to(frame, _bad)


def wrong_address(frame: bytes, address: int, req: Any) -> bytes:
    f = execasync.Decoder().feed(frame)[0]
    other = address % ADDRESS_MAX + 1
    return execasync.encode(other, f.data, f.seq)


def raw_frames(baud: int) -> Any:
    """The framer of replay and learn (the C codec table's exec async decoder)."""
    return CodecFramer(NAME, baud)


def learn(pairs: List[Any]) -> Dict[int, Dict[str, Any]]:
    """Node configs (address -> keys) from (request frame, reply frames) pairs: reply tables."""
    nodes: Dict[int, Dict[bytes, bytes]] = {}
    for request, replies in pairs:
        req = execasync.Decoder().feed(request)[0]
        got = execasync.Decoder().feed(replies[0])[0] if replies else None
        if got is not None and got.ok and got.node == req.node:
            nodes.setdefault(req.node, {})[req.data] = got.data
    return {a: _reply.table_config(rows) for a, rows in nodes.items()}


def garbage(rng: Any, n: int) -> bytes:
    return garbage_without(rng, n, bytes((execasync.DLE,)))
