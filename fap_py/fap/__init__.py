"""FAP (Fast Action Protocol) master and slave nodes, run by libfap's C engine.

Each :class:`Master` or :class:`Slave` owns one handle of libfap's re-entrant
API (``include/fapx.h``): a C engine thread that talks to the serial port,
keeps the protocol's timers and queues the frames and events. Python code
gets exactly the engine C programs get; this module only converts types,
checks arguments and turns C error codes into exceptions. The value types
are in :mod:`fap_py.fap.types`, the line options in :mod:`fap_py.rs485`,
the errors in :mod:`fap_py.errors` (all re-exported here).

Example::

    from fap_py import Master, Slave
    from fap_py.vbus import VirtualBus

    with VirtualBus(ports=2) as bus, \\
         Master(bus.paths[0], 115200, slaves=[7], id_cycle=0.05) as master, \\
         Slave(bus.paths[1], 115200, id=7) as slave:
        master.wait_active([7], timeout=2)
        master.send(b"hello", to=7)
        print(slave.recv(timeout=2))         # Message(source=0, data=b'hello')

Blocking calls (:meth:`Node.recv`, :meth:`Node.wait_event`, ...) release the
GIL while they wait and wait in slices of :data:`WAIT_SLICE` seconds inside
C, so Ctrl-C (``KeyboardInterrupt``) and :meth:`Node.close` from another
thread take effect within one slice. The asyncio methods
(:meth:`Node.arecv`, ``async for``, :meth:`Node.aevents`) are driven by the
engine's notification fd through ``loop.add_reader`` (see
:mod:`fap_py.fap.aio`).
"""
from .._handle import WAIT_SLICE
from ..errors import InvalidTypeError, NotMasterError, SlaveExistsError, UnknownSlaveError
from ..rs485 import DEFAULT_BAUD, RS485, RS485Mode, port_options
from .classic import classic_check
from .daemon import DaemonFapMaster
from .master import Master
from .node import Node
from .slave import Slave
from .types import MASTER_ID, MAX_DATA, MAX_ID, EventKind, Message, SlaveEvent, Stats

# Facts the tools read through fap_py._protocols (never re-typed in a tool).
NODE_MIN: int = 1                       # slave IDs a master polls
NODE_MAX: int = MAX_ID
BROADCAST = None                        # FAP has no broadcast ID

__all__ = [
    "NODE_MIN",
    "NODE_MAX",
    "DEFAULT_BAUD",
    "BROADCAST",
    "MASTER_ID",
    "MAX_DATA",
    "MAX_ID",
    "WAIT_SLICE",
    "classic_check",
    "DaemonFapMaster",
    "EventKind",
    "InvalidTypeError",
    "Master",
    "Message",
    "Node",
    "NotMasterError",
    "RS485",
    "RS485Mode",
    "Slave",
    "SlaveEvent",
    "SlaveExistsError",
    "Stats",
    "UnknownSlaveError",
    "port_options",
]
