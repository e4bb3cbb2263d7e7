"""``fap sim --learn CAPTURE``: a config that reproduces the devices of a recorded bus.

The capture is paired into requests and replies as for a replay (:func:`.replay.build_table`);
then, by protocol:

- exec async and mikroC: one node per address that answered, ``answer = "table"`` with one row
  per distinct request data (its last recorded reply: a device whose answer to the same request
  changed over time is reproduced by its latest answer);
- G485: one device per address that answered, the values it was seen to hold (read replies and
  accepted writes) as the initial values of its private registers (8..100), registers 1..5 as
  its identity.

The result is TOML, checked by the same schema as any config before it is written.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

from .replay import ReplayError, _Framer, build_table


def _frames(protocol: str, data: bytes) -> List[bytes]:
    return [raw for _, raw in _Framer(protocol, 0).feed(data)]


def learn(capture: Any, protocol: str, master_port: Optional[int] = None, source: str = "") -> str:
    """The TOML config text that reproduces ``capture``'s devices."""
    table = build_table(capture, protocol, master_port)
    baud = int(capture.header.get("baud", "0") or 0)
    lines = [f"# learned by fap sim --learn from {source or 'a capture'}",
             "[[bus]]", f'protocol = "{protocol}"']
    if baud:
        lines.append(f"baud = {baud}")
    if protocol in ("exec", "mikroc"):
        nodes = _tables(protocol, table)
        if not nodes:
            raise ReplayError("no device answered in the capture: nothing to learn")
        for address in sorted(nodes):
            lines += ["", "[[bus.node]]", f"address = {address}", 'answer = "table"', "table = ["]
            lines += [f'  {{ request = "{req.hex()}", reply = "{rep.hex()}" }},'
                      for req, rep in nodes[address].items()]
            lines.append("]")
    else:
        devices = _g485(table)
        if not devices:
            raise ReplayError("no device answered in the capture: nothing to learn")
        for address in sorted(devices):
            regs = devices[address]
            lines += ["", "[[bus.node]]", f"address = {address}"]
            ident = [regs.get(r) for r in range(1, 6)]
            if all(v is not None for v in ident):
                lines.append(f"identity = [{', '.join(str(v) for v in ident)}]")
            private = sorted(r for r in regs if 8 <= r <= 100)
            if private:
                lines.append("registers = [")
                lines += [f"  {{ register = {r}, initial = {regs[r]} }}," for r in private]
                lines.append("]")
    text = "\n".join(lines) + "\n"
    from .config import loads
    loads(text, "learned config")      # the schema's word on it, before anyone reads it
    return text


def _tables(protocol: str, table: Any) -> Dict[int, Dict[bytes, bytes]]:
    from .. import execasync, mikroc

    nodes: Dict[int, Dict[bytes, bytes]] = {}
    for request, answers in table.entries.items():
        reply = answers[-1][0]
        frames = _frames(protocol, reply)
        if not frames:
            continue
        if protocol == "exec":
            req = execasync.Decoder().feed(request)[0]
            got = execasync.Decoder().feed(frames[0])[0]
            if got.node != req.node:
                continue
            nodes.setdefault(req.node, {})[req.data] = got.data
        else:
            mreq = mikroc.decode(request)
            mrep = mikroc.decode(frames[0])
            if mrep.from_master or mrep.address != mreq.address:
                continue
            nodes.setdefault(mreq.address, {})[mreq.data] = mrep.data
    return nodes


def _g485(table: Any) -> Dict[int, Dict[int, int]]:
    from ..g485 import codec

    devices: Dict[int, Dict[int, int]] = {}
    writes: List[Tuple[int, int, bytes]] = []
    for request, answers in table.entries.items():
        pkt = codec.Parser().feed(request)[0]
        if not isinstance(pkt, codec.Packet):
            continue
        if pkt.kind is codec.PacketKind.WRITE and pkt.address != codec.BROADCAST:
            writes.append((pkt.address, pkt.register, pkt.data))
            continue
        for reply, _ in answers[-1:]:
            frames = _frames("g485", reply)
            if not frames:
                continue
            regs = devices.setdefault(pkt.address, {})
            rep = codec.Parser().feed(frames[0])[0]
            if pkt.kind is codec.PacketKind.READ_REQUEST and isinstance(rep, codec.Packet) \
                    and rep.kind is codec.PacketKind.READ_RESPONSE:
                for i, v in enumerate(rep.data):
                    regs[pkt.register + i] = v
    for address, register, data in writes:      # a write the device answered later reads of
        if address in devices:
            for i, v in enumerate(data):
                devices[address].setdefault(register + i, v)
    return devices
