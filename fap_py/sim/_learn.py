"""``fap sim --learn CAPTURE``: a config that reproduces the devices of a recorded bus.

The capture is paired into requests and replies as for a replay (:func:`.replay.build_table`);
the protocol's plug-in (``learn(pairs)``) turns the pairs into node configs: exec async and
mikroC one node per address that answered, ``answer = "table"`` with one row per distinct
request data (its last recorded reply); G485 one device per address that answered, with the
values it was seen to hold as identity and initial register values. The result is TOML,
checked by the same schema as any config before it is returned.
"""
from __future__ import annotations

import json
from typing import Any, List, Optional

from ._plugins import plugin
from ._replay import ReplayError, build_table


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)        # a TOML basic string is a JSON string for these values
    if isinstance(v, list):
        if v and all(isinstance(x, dict) for x in v):
            return "[\n" + "".join(f"  {_value(x)},\n" for x in v) + "]"
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    raise ReplayError(f"cannot write {v!r} as TOML")  # pragma: no cover


def learn(capture: Any, protocol: str, master_port: Optional[int] = None, source: str = "") -> str:
    """The TOML config text that reproduces ``capture``'s devices."""
    table = build_table(capture, protocol, master_port)
    proto = plugin(protocol)
    framer = proto.raw_frames
    pairs = [(req, [raw for _, raw in framer(0).feed(answers[-1][0])])
             for req, answers in table.entries.items()]
    nodes = proto.learn(pairs)
    if not nodes:
        raise ReplayError("no device answered in the capture: nothing to learn")
    baud = int(capture.header.get("baud", "0") or 0)
    lines: List[str] = [f"# learned by fap sim --learn from {source or 'a capture'}",
                        "[[bus]]", f"protocol = {_value(proto.NAME)}"]
    if baud:
        lines.append(f"baud = {baud}")
    for address in sorted(nodes):
        lines += ["", "[[bus.node]]", f"address = {address}"]
        lines += [f"{k} = {_value(v)}" for k, v in nodes[address].items()]
    text = "\n".join(lines) + "\n"
    from ._config import loads
    loads(text, "learned config")      # the schema's word on it, before anyone reads it
    return text
