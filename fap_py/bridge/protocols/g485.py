"""The bridge's G485 plug-in: a master on fap_py.g485's G485Master that polls the
register runs of its ``device`` tables and carries out read, write, set and error-word
requests."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Tuple

from ... import _protocols
from ...errors import FapError
from ...g485.codec import MAX_REGISTER, MIN_REGISTER
from .._schema import BridgeConfigError, check_plugin_args, done, in_range, pop, show
from ..buses import BusAdapter, TxError, hex_field, int_field

__all__ = ["ROLES", "DEFAULT_TIMEOUT", "G485Device", "Options", "options", "Adapter"]

ROLES = ("master",)
DEFAULT_TIMEOUT = 0.1   #: per transaction attempt


@dataclass(frozen=True)
class G485Device:
    """A G485 device and the register runs polled on it: ``[(first, count), ...]``."""

    address: int
    registers: Tuple[Tuple[int, int], ...]


@dataclass(frozen=True)
class Options:
    """A G485 bus's own keys."""

    devices: Tuple[G485Device, ...] = ()


def _runs(d: Dict[str, Any], dw: str) -> Tuple[Tuple[int, int], ...]:
    runs = []
    for run in pop(d, "registers", list, dw, []):
        if (not isinstance(run, list) or len(run) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in run)):
            raise BridgeConfigError(f"{dw}.registers: each entry is [first, count], not {show(run)}")
        in_range(run[0], MIN_REGISTER, MAX_REGISTER, f"{dw}.registers first")
        in_range(run[1], 1, MAX_REGISTER + 1 - run[0], f"{dw}.registers count")
        runs.append((run[0], run[1]))
    return tuple(runs)


def options(t: Dict[str, Any], where: str, role: str, proto: _protocols.Protocol) -> Options:
    """Take and check the ``device`` tables (address in the protocol's node range)."""
    check_plugin_args(t, where, role, proto)
    devices: List[G485Device] = []
    for j, d in enumerate(pop(t, "device", list, where)):
        dw = f"{where}.device[{j}]"
        if not isinstance(d, dict):
            raise BridgeConfigError(f"{dw} must be a table")
        d = dict(d)
        address = in_range(pop(d, "address", int, dw), proto.node_min, proto.node_max, f"{dw}.address")
        runs = _runs(d, dw)
        done(d, dw)
        devices.append(G485Device(address, runs))
    if len({d.address for d in devices}) != len(devices):
        raise BridgeConfigError(f"{where}: a device address is listed twice")
    return Options(tuple(devices))


class Adapter(BusAdapter):
    """fap_py.g485.G485Master; polls the configured register runs."""

    HEALTH = {"frames_tx": ("transactions",), "crc_errors": ("frame_errors", "check_mismatches"),
              "timeouts": ("no_response",), "retries": ("retries",)}

    def open(self) -> None:
        from ...g485 import G485Master

        c = self.cfg
        self.engine = G485Master(c.port, c.baud, timeout=c.timeout, retries=c.retries, rs485=c.rs485)

    def configured_nodes(self) -> Tuple[int, ...]:
        return tuple(d.address for d in self.cfg.options.devices)

    def _polls(self) -> bool:
        return any(d.registers for d in self.cfg.options.devices)

    def poll(self) -> None:
        for dev in self.cfg.options.devices:
            for first, count in dev.registers:
                try:
                    data = self._timed(dev.address, self.engine.read, dev.address, first, count)
                except FapError as exc:
                    self._polled(dev.address, None, exc)
                    break          # the device is not answering: skip its other runs this round
                self._polled(dev.address, {"op": "read", "register": first, "data": data.hex()}, None)

    def _check_tx(self, node: int, req: Dict[str, Any]) -> None:
        op = req.get("op")
        if op == "read":
            int_field(req, "register"), int_field(req, "count", 1)
        elif op == "write":
            int_field(req, "register"), hex_field(req)
        elif op == "set":
            command = req.get("command")
            if not isinstance(command, (str, int)) or isinstance(command, bool):
                raise TxError("set needs a command (a SetCommand name or value)")
        elif op != "error_word":
            raise TxError(f"op {str(op)[:40]!r}: a {self.proto.name} bus takes read, write, set or error_word")

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        m = self.engine
        op = req.get("op")
        everyone = node == self.proto.broadcast
        if op == "read":
            register, count = int_field(req, "register"), int_field(req, "count", 1)
            return {"op": op, "register": register,
                    "data": self._timed(node, m.read, node, register, count).hex()}
        if op == "write":
            register, data = int_field(req, "register"), hex_field(req)
            if everyone:
                m.broadcast_write(register, data)
            else:
                self._timed(node, m.write, node, register, data)
            return {"op": op, "register": register, "data": data.hex()}
        if op == "set":
            command = req.get("command")
            if not isinstance(command, (str, int)) or isinstance(command, bool):
                raise TxError("set needs a command (a SetCommand name or value)")
            if everyone:
                m.broadcast_set(command)
            else:
                m.set(node, command)
            return {"op": op, "command": command, "data": ""}
        if op == "error_word":
            return {"op": op, "value": m.error_word(node), "data": ""}
        raise TxError(f"op {op!r}: a {self.proto.name} bus takes read, write, set or error_word")
