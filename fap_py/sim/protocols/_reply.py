"""What an exec async or mikroC node answers: echo, a reply table, or a generator's value."""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

from .._generators import make, to_bytes
from .._schema import HEX, MAX_TABLE, PATTERN, Path, Problem

#: the node keys both protocols share (their plug-ins' NODE_PROPERTIES)
REPLY_PROPERTIES: Dict[str, Any] = {
    "answer": {"enum": ["echo", "table", "value", "none"],
               "description": "echo (default), table, value (the generator's), none"},
    "table": {"type": "array", "maxItems": MAX_TABLE, "items": {
        "type": "object", "additionalProperties": False, "required": ["request", "reply"],
        "properties": {"request": PATTERN, "reply": HEX}},
        "description": "rows tried in order: the first whose pattern matches gives the reply"},
    "default": {**HEX, "description": "table: the reply when no row matches (default: none)"},
    "value": {"$ref": "#/$defs/generator", "description": "answer 'value': its generator"},
    "size": {"type": "integer", "minimum": 1, "maximum": 8, "description": "value: bytes (default 2)"},
    "byteorder": {"enum": ["big", "little"], "description": "value: default big"},
    "signed": {"type": "boolean", "description": "value: default false"},
}


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(text.replace(":", " "))


class Pattern:
    """A request pattern: hex bytes, ``??`` any one byte, a final ``*`` any rest."""

    def __init__(self, text: str) -> None:
        t = text.replace(":", "").replace(" ", "")
        self.rest = t.endswith("*")
        t = t.rstrip("*")
        self.items: List[Optional[int]] = [None if t[i:i + 2] == "??" else int(t[i:i + 2], 16)
                                           for i in range(0, len(t), 2)]

    def match(self, data: bytes) -> bool:
        if len(data) < len(self.items) or (not self.rest and len(data) != len(self.items)):
            return False
        return all(p is None or p == b for p, b in zip(self.items, data))


def check(node: Dict[str, Any], where: Path, max_data: int) -> List[Problem]:
    out: List[Problem] = []
    answer = node.get("answer", "echo")
    if answer == "table" and not node.get("table"):
        out.append(Problem(where + ("table",), "answer 'table' needs a non-empty 'table'"))
    if answer == "value" and "value" not in node:
        out.append(Problem(where, "answer 'value' needs a 'value' generator"))
    for i, row in enumerate(node.get("table", ())):
        for key in ("request", "reply"):
            text = row[key].replace(":", "").replace(" ", "").rstrip("*")
            if len(text) % 2:
                out.append(Problem(where + ("table", i, key), "an odd number of hex digits"))
        if len(row["reply"].replace(":", "").replace(" ", "")) // 2 > max_data:
            out.append(Problem(where + ("table", i, "reply"), f"longer than {max_data} bytes"))
    if "default" in node and len(hexbytes(node["default"])) > max_data:
        out.append(Problem(where + ("default",), f"longer than {max_data} bytes"))
    if node.get("size", 2) > max_data:
        out.append(Problem(where + ("size",), f"{node['size']} bytes: a reply holds at most {max_data}"))
    return out


def table_config(rows: Dict[bytes, bytes]) -> Dict[str, Any]:
    """The node keys of a learned reply table."""
    return {"answer": "table", "table": [{"request": q.hex(), "reply": r.hex()} for q, r in rows.items()]}


class Behaviour:
    """The reply data of one node for a request's data."""

    def __init__(self, node: Dict[str, Any], seed: int) -> None:
        self.answer = node.get("answer", "echo")
        self.table: List[Tuple[Pattern, bytes]] = [(Pattern(r["request"]), hexbytes(r["reply"]))
                                                   for r in node.get("table", ())]
        self.default = hexbytes(node["default"]) if "default" in node else None
        self.gen = make(node["value"], seed) if "value" in node else None
        self.size = node.get("size", 2)
        self.byteorder = node.get("byteorder", "big")
        self.signed = node.get("signed", False)

    def reply(self, data: bytes, t: float) -> Optional[bytes]:
        if self.answer == "echo":
            return data
        if self.answer == "none":
            return None
        if self.answer == "table":
            for pat, rep in self.table:
                if pat.match(data):
                    return rep
            return self.default
        assert self.gen is not None
        return to_bytes(self.gen(t), self.size, self.byteorder, self.signed)
