"""Toy nodes of ``fap sim``: each answers a request with the data reversed (what the toy
slave does), over the port layer with the toy's own codec. It proves that a fifth
protocol's simulator is this one file, with no edit to fap_py."""
from __future__ import annotations

from typing import Any, Dict, List, Optional

from fap_py.sim.protocols import REPLY_KINDS, Path, Problem, Request, flip_to, garbage_without

from ... import binding as toy

NAME = "toy"
ADDRESS_MIN, ADDRESS_MAX = toy.NODE_MIN, toy.NODE_MAX
ADDRESS_RESERVED = ()
FAULTS = REPLY_KINDS
NODE_PROPERTIES: Dict[str, Any] = {}


def check_node(node: Dict[str, Any], where: Path) -> List[Problem]:
    return []


class _Decoder:
    idle_timeout = 0.2

    def __init__(self) -> None:
        self._dec = toy.Decoder()

    def feed(self, data: bytes) -> List[Request]:
        return [Request(node, data) for node, data in self._dec.feed(data) if not node & toy.REPLY]

    def idle(self) -> List[Request]:
        return []


def request_decoder(baud: int) -> _Decoder:
    return _Decoder()


class Node:
    def __init__(self, address: int, cfg: Dict[str, Any], seed: int) -> None:
        self.address = address

    def hear(self, msg: Any) -> None:
        pass

    def answer(self, data: bytes, t: float) -> Optional[bytes]:
        return toy.encode(self.address, bytes(reversed(data)), reply=True)


def make_node(address: int, cfg: Dict[str, Any], seed: int) -> Node:
    return Node(address, cfg, seed)


def bad_check(frame: bytes) -> bytes:
    return flip_to(frame, lambda f: not toy.Decoder().feed(f))


def wrong_address(frame: bytes, address: int, req: Any) -> bytes:
    other = address + 1 if address < ADDRESS_MAX else ADDRESS_MIN
    return toy.encode(other, frame[3:-1], reply=True)


def garbage(rng: Any, n: int) -> bytes:
    return garbage_without(rng, n, bytes((toy.START,)))
