"""A FAP slave (ID 1..31) on a port."""
from __future__ import annotations

from typing import Any, Optional, Union

from ..errors import (
    InvalidValueError,
)
from .node import Node, PathLike, _int, _slave_id
from .types import (
    MASTER_ID,
    MAX_ID,
)


class Slave(Node):
    """A FAP slave (ID 1..31): answers the master's queries, sends in its turn.

    Args:
        port: serial device path.
        baudrate: line speed.
        id: this slave's ID, 1..31.
        Other keyword options as for :class:`Master` (``rs485``, queue
        depths, ``byte_gap``, ``reopen_interval``, ``send_budget``...).
    """

    _mode = 1

    def __init__(self, port: PathLike, baudrate: int = 115200, *, id: int,
                 **options: Any) -> None:
        super().__init__(port, baudrate, node_id=_slave_id(id, "id"), **options)
        self._dests = frozenset(range(MAX_ID + 1)) - {self.id}

    def _check_dest(self, to: Any) -> int:
        dest = _int(to, "to (a node ID)", 0, MAX_ID)
        if dest == self.id:
            raise InvalidValueError(f"a slave cannot send to its own ID {dest}")
        return dest

    def send(self, data: Union[bytes, bytearray, memoryview], to: int = MASTER_ID,
             timeout: Optional[float] = 0.0) -> None:
        """Queue ``data`` for node ``to`` (default the master); sent when polled.

        See :meth:`Node.send`.
        """
        Node.send(self, data, to, timeout)   # not super(): one object less per message
