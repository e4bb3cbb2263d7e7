"""mikroC nodes of ``fap sim``: echo, a reply table or a generator's value, in Python over the
port layer with the package's mikroC codec (``fap_py.mikroc.encode`` / ``Decoder``)."""
from __future__ import annotations

from typing import Any, Dict, List, Optional

from ... import mikroc
from .._faults import REPLY_KINDS
from .._responder import CodecFramer, Request, flip_to, garbage_without
from .._schema import Path, Problem
from . import _reply

NAME = "mikroc"
ADDRESS_MIN, ADDRESS_MAX = mikroc.NODE_MIN, mikroc.NODE_MAX
ADDRESS_RESERVED = (mikroc.BROADCAST,)
FAULTS = REPLY_KINDS
NODE_PROPERTIES: Dict[str, Any] = dict(_reply.REPLY_PROPERTIES)


def check_node(node: Dict[str, Any], where: Path) -> List[Problem]:
    return _reply.check(node, where, mikroc.MAX_DATA)


def request_size(msg: Any) -> int:
    """The request's bytes on the wire (a direction-request fault draws each)."""
    return len(mikroc.encode(msg.address, msg.data))


class _Decoder:
    idle_timeout = 0.2

    def __init__(self) -> None:
        self._dec = mikroc.Decoder()

    def feed(self, data: bytes) -> List[Request]:
        out = []
        for m in self._dec.feed(data):
            if isinstance(m, mikroc.Message) and m.from_master:
                out.append(Request(None if m.address == mikroc.BROADCAST else m.address, m))
        return out

    def idle(self) -> List[Request]:
        return []


def request_decoder(baud: int) -> _Decoder:
    return _Decoder()


class Node:
    def __init__(self, address: int, cfg: Dict[str, Any], seed: int) -> None:
        self.address = address
        self.behaviour = _reply.Behaviour(cfg, seed)

    def hear(self, msg: Any) -> None:   # a broadcast: never answered
        pass

    def answer(self, msg: mikroc.Message, t: float) -> Optional[bytes]:
        data = self.behaviour.reply(msg.data, t)
        return None if data is None else mikroc.encode(self.address, data, from_master=False)


def make_node(address: int, cfg: Dict[str, Any], seed: int) -> Node:
    return Node(address, cfg, seed)


def _bad(frame: bytes) -> bool:
    got = mikroc.Decoder().feed(frame)
    return len(got) == 1 and isinstance(got[0], mikroc.ChecksumError)


def bad_check(frame: bytes) -> bytes:
    return flip_to(frame, _bad)


def wrong_address(frame: bytes, address: int, req: Any) -> bytes:
    m = mikroc.decode(frame)
    other = address + 1 if address + 1 <= ADDRESS_MAX else ADDRESS_MIN
    if other == mikroc.BROADCAST:
        other += 1
    return mikroc.encode(other, m.data, from_master=False)


def raw_frames(baud: int) -> Any:
    """The framer of replay and learn (the C codec table's mikroC decoder)."""
    return CodecFramer(NAME, baud)


def learn(pairs: List[Any]) -> Dict[int, Dict[str, Any]]:
    """Node configs (address -> keys) from (request frame, reply frames) pairs: reply tables."""
    nodes: Dict[int, Dict[bytes, bytes]] = {}
    for request, replies in pairs:
        req = mikroc.decode(request)
        if not replies:
            continue
        rep = mikroc.decode(replies[0])
        if not rep.from_master and rep.address == req.address:
            nodes.setdefault(req.address, {})[req.data] = rep.data
    return {a: _reply.table_config(rows) for a, rows in nodes.items()}


def garbage(rng: Any, n: int) -> bytes:
    return garbage_without(rng, n, bytes((mikroc.START_BYTE,)))
