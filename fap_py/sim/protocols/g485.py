"""G485 devices of ``fap sim``: :class:`fap_py.g485.SimDevice` (registers, modes, error word,
EEPROM) with typed registers whose values can come from generators, on the sim's responder."""
from __future__ import annotations

from typing import Any, Dict, List, Optional

from ...g485 import codec
from ...g485.device import RegisterSpec, SimDevice
from .._faults import REPLY_KINDS
from .._generators import make, to_bytes
from .._responder import Request, flip_to, garbage_without
from .._schema import MAX_LIST, Path, Problem

NAME = "g485"
ADDRESS_MIN, ADDRESS_MAX = codec.MIN_SLAVE_ADDRESS, codec.MAX_SLAVE_ADDRESS
FAULTS = REPLY_KINDS + ("error_reply",)
#: a device's ID is its register 7: a write, or a reset that loads an EEPROM image, moves it
ADDRESS_CAN_CHANGE = True

#: register types: bytes, signedness (big-endian over consecutive registers)
TYPES = {"u8": (1, False), "i8": (1, True), "u16": (2, False), "i16": (2, True),
         "u32": (4, False), "i32": (4, True)}

NODE_PROPERTIES: Dict[str, Any] = {
    "identity": {"type": "array", "minItems": 5, "maxItems": 5,
                 "items": {"type": "integer", "minimum": 0, "maximum": 255},
                 "description": "registers 1..5 (protocol version, class, subclass, hardware, software)"},
    "eeprom": {"type": "string", "maxLength": 4096, "description": "EEPROM image file (persistence)"},
    "wake_up_loss": {"type": "boolean", "description": "lose the first burst heard after power-on "
                     "or reset (baud detection above 28,800 baud; default false)"},
    "registers": {"type": "array", "maxItems": MAX_LIST, "items": {
        "type": "object", "additionalProperties": False, "required": ["register"],
        "properties": {
            "register": {"type": "integer", "minimum": 8, "maximum": 100,
                         "description": "the first register (private registers 8..100)"},
            "type": {"enum": list(TYPES), "description": "default u8; wider types are big-endian "
                     "over consecutive registers"},
            "access": {"enum": ["R", "W", "RW"], "description": "default RW"},
            "initial": {"type": "integer", "description": "default 0"},
            "saved": {"type": "boolean", "description": "kept in EEPROM (default true)"},
            "value": {"$ref": "#/$defs/generator", "description": "a generator (instead of data/initial)"},
        }}},
}


def check_node(node: Dict[str, Any], where: Path) -> List[Problem]:
    out: List[Problem] = []
    used: Dict[int, int] = {}
    for i, r in enumerate(node.get("registers", ())):
        size, signed = TYPES[r.get("type", "u8")]
        first = r["register"]
        if first + size - 1 > 100:
            out.append(Problem(where + ("registers", i, "type"), f"{r.get('type')} at {first} ends past register 100"))
        lo, hi = (-(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1) if signed else (0, (1 << (8 * size)) - 1)
        if not lo <= r.get("initial", 0) <= hi:
            out.append(Problem(where + ("registers", i, "initial"), f"{r['initial']} is outside {lo}..{hi}"))
        for reg in range(first, first + size):
            if reg in used:
                out.append(Problem(where + ("registers", i, "register"), f"register {reg} is already "
                                   f"registers[{used[reg]}]'s"))
                break
            used[reg] = i
    return out


class _Decoder:
    def __init__(self, baud: int) -> None:
        self._p = codec.Parser()
        self.idle_timeout = max(0.02, 50.0 / baud) if baud else 0.02

    def _items(self, events: List[Any]) -> List[Request]:
        out = []
        for ev in events:
            if isinstance(ev, codec.Packet):
                # a broadcast, or another device's reply (to the master): every device hears it
                # (a device just powered on loses it to baud detection) and none answers
                target = ev.address
                out.append(Request(None if target == codec.BROADCAST or target == codec.MASTER_ADDRESS
                                   else target, ev))
            else:
                out.append(Request(None, ev))
        return out

    def feed(self, data: bytes) -> List[Request]:
        return self._items(self._p.feed(data))

    @property
    def partial(self) -> bool:
        return bool(self._p.buffered)

    def idle(self) -> List[Request]:
        return self._items(self._p.expire()) if self._p.buffered else []

    def clear(self) -> None:
        self._p.clear()


def request_decoder(baud: int) -> _Decoder:
    return _Decoder(baud)


class Node:
    """A :class:`SimDevice` plus generators that set its registers before each request."""

    def __init__(self, address: int, cfg: Dict[str, Any], seed: int) -> None:
        private: Dict[int, Any] = {}
        self.gens: List[tuple] = []
        for r in cfg.get("registers", ()):
            size, signed = TYPES[r.get("type", "u8")]
            raw = to_bytes(r.get("initial", 0), size, "big", signed)
            for i in range(size):
                private[r["register"] + i] = RegisterSpec(r.get("access", "RW"), raw[i], r.get("saved", True))
            if "value" in r:
                self.gens.append((r["register"], size, signed, make(r["value"], seed + r["register"])))
        kw: Dict[str, Any] = {}
        if "identity" in cfg:
            kw["identity"] = tuple(cfg["identity"])
        if "eeprom" in cfg:
            kw["eeprom_path"] = cfg["eeprom"]
        if cfg.get("wake_up_loss"):
            kw["wake_up_loss"] = True
        self.device = SimDevice(address, private=private, seed=seed, **kw)
        # a device that loses the first burst after power-on loses it whoever it was for
        self.hears_all = self.device.wake_up_loss

    @property
    def address(self) -> int:
        """The ID it answers at now (register 7: a write or an EEPROM image moves it)."""
        return self.device.address

    def hear(self, event: Any) -> None:
        self.device.handle(event)     # broadcasts and discards: no reply

    def answer(self, packet: Any, t: float) -> Optional[bytes]:
        if self.gens and packet.kind is codec.PacketKind.READ_REQUEST:
            for reg, size, signed, gen in self.gens:
                for i, b in enumerate(to_bytes(gen(t), size, "big", signed)):
                    self.device.set_register(reg + i, b)
        return self.device.handle(packet)


def error_reply(node: Node, word: int) -> None:
    """The ``error_reply`` fault: the device reports ``word``'s bits in its error word (a
    Get-Error-Word request answers them; a Set clear-error-word clears them until the next
    transaction the fault applies to)."""
    node.device.error_word |= word


def make_node(address: int, cfg: Dict[str, Any], seed: int) -> Node:
    return Node(address, cfg, seed)


def _bad(frame: bytes) -> bool:
    got = codec.Parser().feed(frame)
    return len(got) == 1 and isinstance(got[0], codec.Discarded) and got[0].issue is codec.ParseIssue.BAD_CHECK


def bad_check(frame: bytes) -> bytes:
    return flip_to(frame, _bad)


def wrong_address(frame: bytes, address: int, req: Any) -> bytes:
    """A G485 reply carries the master's address (SMA_R): the reply sent with the device's
    own address byte instead, which no master takes for a reply."""
    p = codec.reply_packet(frame)
    return codec.frame((address << 1) | 1, p.pid, p.data)


class _RawFrames:
    def __init__(self) -> None:
        self._p = codec.Parser()

    def feed(self, data: bytes) -> List[Any]:
        return [(None, ev.raw) for ev in self._p.feed(data) if isinstance(ev, codec.Packet)]


def raw_frames(baud: int) -> Any:
    """The framer of replay and learn (``fap_py.g485.codec.Parser``; no stream offsets)."""
    return _RawFrames()


def learn(pairs: List[Any]) -> Dict[int, Dict[str, Any]]:
    """Device configs from (request frame, reply frames) pairs: the register values each
    answering device was seen to hold (read replies; writes to it) as identity and initial
    values."""
    devices: Dict[int, Dict[int, int]] = {}
    writes = []
    for request, replies in pairs:
        pkt = codec.Parser().feed(request)[0]
        if not isinstance(pkt, codec.Packet):
            continue
        if pkt.kind is codec.PacketKind.WRITE and pkt.address != codec.BROADCAST:
            writes.append((pkt.address, pkt.register, pkt.data))
            continue
        if not replies:
            continue
        regs = devices.setdefault(pkt.address, {})
        rep = codec.Parser().feed(replies[0])[0]
        if pkt.kind is codec.PacketKind.READ_REQUEST and isinstance(rep, codec.Packet) \
                and rep.kind is codec.PacketKind.READ_RESPONSE:
            for i, v in enumerate(rep.data):
                regs[pkt.register + i] = v
    for address, register, data in writes:
        if address in devices:
            for i, v in enumerate(data):
                devices[address].setdefault(register + i, v)
    out: Dict[int, Dict[str, Any]] = {}
    for address, regs in devices.items():
        cfg: Dict[str, Any] = {}
        ident = [regs.get(r) for r in range(1, 6)]
        if all(v is not None for v in ident):
            cfg["identity"] = ident
        private = sorted(r for r in regs if 8 <= r <= 100)
        if private:
            cfg["registers"] = [{"register": r, "initial": regs[r]} for r in private]
        out[address] = cfg
    return out


class _SerialPort:
    """A pyserial URL (``socket://`` ...; fap_py.g485.transport.SerialIO) with the port
    layer's calls the responder makes (read with a timeout, write, reopen, close)."""

    _SLICE_S = 0.05   # a read waits in slices: a close() from another thread ends it

    def __init__(self, io: Any) -> None:
        self._io = io
        self.baudrate = io.baudrate
        self.path = io.name

    def read(self, n: int, timeout: float = 0.0) -> bytes:
        import time

        from ...errors import ClosedError

        if self._io.closed:
            raise ClosedError(f"{self.path}: port closed")
        try:
            return bytes(self._io.read_some(n, time.monotonic() + min(timeout, self._SLICE_S)))
        except Exception:
            if self._io.closed:   # closed under the read: the responder is stopping
                raise ClosedError(f"{self.path}: port closed") from None
            raise

    def write(self, data: bytes) -> int:
        self._io.write(data)
        return len(data)

    def reopen(self) -> None:
        self._io.reopen()

    def close(self) -> None:
        self._io.close()


def open_port(path: str, baud: int, rs485: Any) -> Any:
    """A device path or libfap's tcp:// / rfc2217:// through the port layer; a pyserial URL
    (``socket://``, ``loop://``: what ``fap g485`` has always taken) through pyserial."""
    from ...port import Port, port_kind

    if port_kind(path) != "other":
        return Port(path, baud, rs485)
    from ...g485.transport import open_io

    return _SerialPort(open_io(path, baud, rs485=rs485))


def garbage(rng: Any, n: int) -> bytes:
    return garbage_without(rng, n, b"\xff")
