"""The FAP value types and limits: messages, events, counters. Sans-I/O.

Every number here comes from the compiled C core (``include/fapx.h``)
through cffi; nothing is typed again in Python.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import List

from .._native import lib
from .._stats import Counters

__all__ = ["MASTER_ID", "MAX_ID", "MAX_DATA", "EventKind", "Message", "SlaveEvent", "Stats",
           "mask_ids"]

MASTER_ID: int = 0                      #: the master's ID (fixed by the protocol: IDs 1.. are slaves)
MAX_ID: int = lib.FAPX_MAX_ID           #: slave IDs are 1..MAX_ID
MAX_DATA: int = lib.FAPX_MAX_DATA       #: bytes per DATA frame


class EventKind(enum.IntEnum):
    """What a :class:`SlaveEvent` reports (``fapx_event_type``)."""

    SLAVE_ACTIVE = lib.FAPX_EV_SLAVE_ACTIVE    #: master: the slave answered QUERY_ID
    SLAVE_INACTIVE = lib.FAPX_EV_SLAVE_INACTIVE  #: master: the slave missed DATA_DONE (an ID cycle follows)
    ID_TIMEOUT = lib.FAPX_EV_ID_TIMEOUT      #: master: the slave did not answer QUERY_ID
    QUERIED = lib.FAPX_EV_QUERIED         #: slave: the master queried us (we answered)
    RX = lib.FAPX_EV_RX              #: (C callback only; never queued)
    PORT_LOST = lib.FAPX_EV_PORT_LOST       #: the port failed; the engine retries to open it
    PORT_REOPENED = lib.FAPX_EV_PORT_REOPENED   #: the port is back
    RX_OVERFLOW = lib.FAPX_EV_RX_OVERFLOW     #: a DATA frame from ``id`` was dropped: receive queue full


@dataclass(frozen=True)
class Message:
    """A DATA frame received by this node."""

    source: int   #: sender ID (0 = the master)
    data: bytes   #: 1..1024 bytes

    def __repr__(self) -> str:
        shown = self.data if len(self.data) <= 32 else self.data[:32]
        more = "" if len(self.data) <= 32 else f"...+{len(self.data) - 32}"
        return f"Message(source={self.source}, data={shown!r}{more})"


_new = object.__new__


def _new_message(source: int, data: bytes) -> Message:
    """``Message(source, data)`` for the receive path, about half the cost: the
    frozen dataclass's ``__init__`` sets each field through ``object.__setattr__``;
    this fills the instance dict directly. Only for values the engine produced
    (an int ID and bytes): nothing is checked, as ``__init__`` checks nothing."""
    m = _new(Message)
    d = m.__dict__
    d["source"] = source
    d["data"] = data
    return m


@dataclass(frozen=True)
class SlaveEvent:
    """An event from the engine: slave state changes, port loss and return."""

    kind: EventKind  #: what happened
    id: int          #: the slave (master events) or this node's ID (port/queried events)
    time_ns: int     #: CLOCK_MONOTONIC time of the event (``time.monotonic_ns()`` clock)

    @property
    def name(self) -> str:
        """The C name of the kind, e.g. ``slave-active``."""
        return self.kind.name.lower().replace("_", "-")

    def __str__(self) -> str:
        return f"{self.name} id={self.id}"


@dataclass(frozen=True)
class Stats(Counters):
    """Counters of a node since it opened (``fapx_stats``)."""

    frames_tx: int           #: valid frames sent (all types)
    frames_rx: int           #: valid frames received (all types, any destination)
    bytes_tx: int            #: wire bytes sent
    bytes_rx: int            #: wire bytes received
    data_tx: int             #: DATA frames sent
    data_rx: int             #: DATA frames delivered to this node
    crc_errors: int          #: complete frames with a bad CRC
    framing_errors: int      #: bad size, msg/size mismatch
    gap_timeouts: int        #: partial frames abandoned after the inter-byte gap
    garbage_bytes: int       #: bytes skipped while looking for a marker
    id_timeouts: int         #: master: QUERY_ID unanswered
    data_done_timeouts: int  #: master: DATA_DONE missing (slave marked inactive)
    collisions: int          #: echo mismatches reported by the port layer
    cycles: int              #: master: complete data cycles
    id_cycles: int           #: master: complete ID cycles
    polls: int               #: SEND_DATA -> DATA_DONE turns completed
    rx_dropped: int          #: DATA lost to a full receive queue
    tx_dropped: int          #: queued frames discarded
    write_errors: int        #: failed port writes
    port_lost: int           #: times the port failed
    port_reopened: int       #: times it came back
    unexpected: int          #: valid frames that fit no protocol state
    ev_dropped: int          #: events lost to a full event queue
    tx_to_inactive: int      #: master: DATA sent to a slave not active at the time
    tx_unconfirmed: int      #: master: DATA sent to a slave then marked inactive
    tx_abandoned: int        #: frames a close dropped because the line would not take them


def mask_ids(mask: int) -> List[int]:
    """The slave IDs whose bits are set in a ``fapx_*_mask`` value, ascending."""
    if type(mask) is not int or not 0 <= mask <= 0xFFFFFFFF:
        from ..errors import InvalidValueError
        raise InvalidValueError(f"mask must be a 32-bit slave mask, not {mask!r}")
    return [i for i in range(1, MAX_ID + 1) if mask >> i & 1]
