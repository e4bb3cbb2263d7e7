"""The monitor's per-protocol plug-ins, one module per protocol of the table.

``fap_py._protocols.get(name).plugin("monitor")`` imports ``<package>.monitor.protocols.<name>``
(a protocol out of tree keeps its plug-in under its own package). A plug-in holds:

- ``FIELDS``: the fields of a good frame, in output order (the JSON schema);
- ``decoder(baud=0)``: a fresh :class:`fap_py.monitor.decoders.Decoder` (the C codec
  table through :class:`~fap_py.monitor.decoders.CodecDecoder`, or the protocol's own
  Python parser);
- ``summary(event)``: a good frame's addresses and message, for the human line;
- optionally ``label(event)``: the text a pcap record carries for a good frame (its message
  type), or None; without it the text is empty;
- ``pair(event, asked)``: ``(node, role, key)`` for the statistics: the node a good frame
  counts for (None: not a frame, e.g. a wake-up preamble), ``"req"``, ``"ans"`` or None,
  and the key an answer must match (``asked`` is the pending request's key, or None);
- optionally ``DIRECTIONLESS = True``: request and answer frames look alike (exec
  async), so on a live port (no sender port) a frame repeating the pending request
  byte for byte is its retry, not its answer;
- optionally ``DISSECTOR``: the Wireshark dissector's name and filter prefix in
  ``dissectors/fap_monitor.lua`` (default: the protocol's name), whose fields must be
  ``<DISSECTOR>.<field>`` for every field of ``FIELDS`` (a test checks it);

docs/monitor.md, "Plug-ins", has the contract.
"""

__all__: list = []
