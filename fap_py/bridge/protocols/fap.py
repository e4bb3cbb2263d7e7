"""The bridge's FAP plug-in: a FAP master (polls its slaves) or slave (answers the
master) on fap_py.fap's engine; its keys ``slaves``/``id_cycle``/``data_done_timeout``
(master) or ``id`` (slave)."""
from __future__ import annotations

import logging
import os
import select
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Tuple

from ... import _protocols
from ...errors import FapError
from ...fap import MASTER_ID, MAX_DATA
from .._schema import check_plugin_args, id_list, in_range, pop
from ..buses import BusAdapter, TxError, hex_field

log = logging.getLogger(__name__)

ROLES = ("master", "slave")
#: Home Assistant: a FAP node has no request/reply, so no reply time, errors or timeouts
REPLY_METRICS = False
DEFAULT_TIMEOUT = 1.0   #: how long a tx waits for room in the engine's transmit queue
#: received messages the engine holds for the bridge: slack for the moments the bridge's
#: threads are not scheduled (a loaded host); the engine's own default is 256
RX_QUEUE = 4096


@dataclass(frozen=True)
class Options:
    """A FAP bus's own keys."""

    slaves: Tuple[int, ...] = ()                 #: master: the slaves it lists
    id_cycle: Optional[float] = None             #: master: seconds between ID cycles
    data_done_timeout: Optional[float] = None    #: master: SEND_DATA -> DATA_DONE limit
    id: int = 0                                  #: slave: this bridge's slave ID
    rx_queue: int = RX_QUEUE                     #: the engine's receive queue (messages)


def options(t: Dict[str, Any], where: str, role: str, proto: _protocols.Protocol) -> Options:
    """Take and check a FAP bus's own keys out of ``t``."""
    check_plugin_args(t, where, role, proto)
    rx_queue = in_range(pop(t, "rx_queue", int, where, RX_QUEUE), 1, 1 << 20, f"{where}.rx_queue")
    if role == "slave":
        return Options(id=in_range(pop(t, "id", int, where), proto.node_min, proto.node_max, f"{where}.id"),
                       rx_queue=rx_queue)
    kw: Dict[str, Any] = {"slaves": id_list(pop(t, "slaves", list, where), proto.node_min, proto.node_max,
                                            f"{where}.slaves"), "rx_queue": rx_queue}
    for key in ("id_cycle", "data_done_timeout"):
        if key in t:
            kw[key] = in_range(float(pop(t, key, (int, float), where)), 0.001, 3600, f"{where}.{key}")
    return Options(**kw)


class Adapter(BusAdapter):
    """fap_py.fap.Master or fap_py.fap.Slave; a reader thread waits on the engine's fd."""

    HEALTH = {"frames_rx": ("frames_rx",), "frames_tx": ("frames_tx",), "crc_errors": ("crc_errors",),
              "timeouts": ("id_timeouts", "data_done_timeouts"), "collisions": ("collisions",)}

    _wake: Optional[Tuple[int, int]] = None   # a pipe that wakes the reader at stop

    def _accepts(self, node: int) -> bool:
        return node == MASTER_ID or super()._accepts(node)   # a slave bus sends to the master

    def configured_nodes(self) -> Tuple[int, ...]:
        o = self.cfg.options
        return o.slaves if self.cfg.role == "master" else (MASTER_ID,)

    def open(self) -> None:
        from ...fap import Master, Slave

        c, o = self.cfg, self.cfg.options
        if c.role == "master":
            self.engine = Master(c.port, c.baud, slaves=o.slaves, rs485=c.rs485, rx_queue=o.rx_queue,
                                 id_cycle=o.id_cycle, data_done_timeout=o.data_done_timeout)
            for sid in o.slaves:
                self.sink.state(c.name, sid, False)
        else:
            self.engine = Slave(c.port, c.baud, id=o.id, rs485=c.rs485, rx_queue=o.rx_queue)

    def start(self) -> None:
        self._wake = os.pipe()
        super().start()
        self._spawn(self._reader, "reader")

    def stop(self) -> None:
        self._stop.set()
        if self._wake is not None:
            os.write(self._wake[1], b"x")
        super().stop()
        if self._wake is not None:
            for fd in self._wake:
                os.close(fd)
            self._wake = None

    def _check_tx(self, node: int, req: Dict[str, Any]) -> None:
        self._data(node, req)

    def _data(self, node: int, req: Dict[str, Any]) -> bytes:
        """A FAP tx's bytes: op ``send``, 1..MAX_DATA bytes of hex, to a listed slave."""
        op = req.get("op", "send")
        if op != "send":
            raise TxError(f"op {str(op)[:40]!r}: a {self.proto.name} bus only sends")
        data = hex_field(req)
        if not 1 <= len(data) <= MAX_DATA:
            raise TxError(f"data of {len(data)} bytes (a FAP message is 1..{MAX_DATA})")
        if self.cfg.role == "master" and node not in self.cfg.options.slaves:
            raise TxError(f"node {node} is not one of this bus's slaves "
                          f"({', '.join(map(str, self.cfg.options.slaves))})")
        return data

    def _execute(self, node: int, req: Dict[str, Any]) -> Optional[Dict[str, Any]]:
        self.engine.send(self._data(node, req), to=node, timeout=self.cfg.timeout)
        return None

    def _reader(self) -> None:
        from ...fap import EventKind

        eng, name, wake = self.engine, self.cfg.name, self._wake
        if wake is None:   # start() opens the pipe before the reader runs
            return
        poller = select.poll()
        poller.register(eng.fileno(), select.POLLIN)
        poller.register(wake[0], select.POLLIN)
        active = {EventKind.SLAVE_ACTIVE: True, EventKind.SLAVE_INACTIVE: False,
                  EventKind.ID_TIMEOUT: False}
        while not self._stop.is_set():
            poller.poll(1000)
            if self._stop.is_set():
                return
            try:
                batch: List[Tuple[int, Dict[str, Any]]] = []
                while len(batch) < 500:     # what is queued now: one disk transaction
                    msg = eng.recv_nowait()
                    if msg is None:
                        break
                    batch.append((msg.source, {"data": msg.data.hex()}))
                if batch:
                    self.counters["rx"] += len(batch)
                    for source, _ in batch:
                        self.node(source).rx += 1
                    self.sink.rx_many(name, batch)
                for ev in eng.events(0):
                    if ev.kind in active:
                        self.sink.state(name, ev.id, active[ev.kind])
                    elif ev.kind == EventKind.QUERIED:
                        self.sink.state(name, MASTER_ID, True)
                    elif ev.kind == EventKind.RX_OVERFLOW:   # counted in engine.rx_dropped
                        self.counters["rx_overflow"] += 1
                        if self.counters["rx_overflow"] == 1:
                            log.warning("bus %s: receive queue full, messages dropped (the bridge is "
                                        "slower than the bus); see stats engine.rx_dropped", name)
                    elif ev.kind in (EventKind.PORT_LOST, EventKind.PORT_REOPENED):
                        log.warning("bus %s: %s", name, ev)
            except FapError as exc:   # closed under us at stop
                if not self._stop.is_set():
                    log.error("bus %s: reader stopped: %s", name, exc)
                return
            except Exception:   # the reader outlives any one failure (it is the bus's only reader)
                self.counters["reader_errors"] += 1
                if self.counters["reader_errors"] <= 3:
                    log.exception("bus %s: reader error (it goes on reading)", name)
