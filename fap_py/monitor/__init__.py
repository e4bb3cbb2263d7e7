"""``fap monitor``: decode a bus of FAP, exec async, mikroC or G485 frames.

The decoding is done by each protocol's own receiver codec (see
:mod:`fap_py.monitor.decoders`); this package adds timing, statistics,
JSON, pcap output, the Wireshark dissector and an extcap entry point.
"""
from typing import Any

from .core import Monitor, Record
from .decoders import PROTOCOLS, Event, make_decoder


def __getattr__(name: str) -> Any:
    """``FIELDS``: each protocol's fields, from the plug-ins (see decoders.fields)."""
    if name == "FIELDS":
        from .decoders import fields

        return fields()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FIELDS", "PROTOCOLS", "Event", "Monitor", "Record", "make_decoder"]
