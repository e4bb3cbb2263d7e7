"""``fap monitor``: decode a bus of FAP, exec async, mikroC or G485 frames.

The decoding is done by each protocol's own receiver codec (see
:mod:`fap_py.monitor.decoders`); this package adds timing, statistics,
JSON, pcap output, the Wireshark dissector and an extcap entry point.
"""
from .core import Monitor, Record
from .decoders import FIELDS, PROTOCOLS, Event, make_decoder

__all__ = ["FIELDS", "PROTOCOLS", "Event", "Monitor", "Record", "make_decoder"]
