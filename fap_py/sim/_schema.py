"""The one schema of a ``fap sim`` config, defined once here as JSON Schema (draft 2020-12).

:data:`SCHEMA` is what ``fap sim --schema`` prints; :func:`validate` checks a loaded config
against the same dict with this module's own validator of the subset the schema uses
(``type``, ``properties``, ``required``, ``additionalProperties``, ``enum``, ``const``,
``minimum``/``maximum``, ``minItems``/``maxItems``, ``maxLength``, ``pattern``, ``items``,
``oneOf``, ``$ref`` to ``$defs``), so jsonschema is not a dependency. A protocol's node keys
come from its plug-in (``fap_py.sim.protocols.<name>.NODE_PROPERTIES``), so the schema of
a fifth protocol is its plug-in's.
"""
from __future__ import annotations

import re
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

from ._faults import DIRECTIONS, KINDS, MAX_SCHEDULE_S

Path = Tuple[Union[str, int], ...]

#: limits that keep a hostile config from eating the machine
MAX_BUSES = 16
MAX_NODES = 256          # node entries per bus (a range entry counts once, expands to <= 256)
MAX_TABLE = 1024         # reply-table rows per node
MAX_HEX = 2 * 512        # hex digits of one pattern or reply
MAX_LIST = 1024          # step lists, register lists, periodic messages
MAX_FAULTS = 256

HEX = {"type": "string", "maxLength": MAX_HEX, "pattern": r"^([0-9a-fA-F]{2}|[ :])*$",
       "description": "bytes as hex (spaces and ':' allowed)"}
PATTERN = {"type": "string", "maxLength": MAX_HEX + 1, "pattern": r"^([0-9a-fA-F]{2}|\?\?|[ :])*\*?$",
           "description": "request bytes as hex; '??' matches any one byte, a final '*' any rest"}

GENERATOR: Dict[str, Any] = {
    "type": "object",
    "description": "a value that changes by itself (docs/sim.md, 'Value generators')",
    "required": ["kind"],
    "additionalProperties": False,
    "properties": {
        "kind": {"enum": ["const", "counter", "ramp", "sine", "square", "random", "steps", "hook"]},
        "value": {"type": "number", "description": "const: the value"},
        "start": {"type": "number", "description": "counter: first value (default 0)"},
        "step": {"type": "number", "description": "counter: increment (default 1)"},
        "every": {"type": "number", "minimum": 0,
                  "description": "counter/steps: seconds per step; 0 (default): one step per read"},
        "wrap": {"type": "number", "description": "counter: value wraps to start at this bound"},
        "low": {"type": "number", "description": "ramp/square/random: low end (default 0)"},
        "high": {"type": "number", "description": "ramp/square/random: high end (default 100)"},
        "period": {"type": "number", "minimum": 0, "description": "ramp/sine/square: seconds (default 10)"},
        "amplitude": {"type": "number", "description": "sine (default 1)"},
        "offset": {"type": "number", "description": "sine: centre value (default 0)"},
        "phase": {"type": "number", "description": "sine: phase in periods (default 0)"},
        "duty": {"type": "number", "minimum": 0, "maximum": 1, "description": "square: high share (default 0.5)"},
        "seed": {"type": "integer", "description": "random: seed (default: the sim's seed)"},
        "integer": {"type": "boolean", "description": "random: whole numbers (default true)"},
        "values": {"type": "array", "maxItems": MAX_LIST, "items": {"type": "number"},
                   "description": "steps: the values in turn (cycled)"},
        "function": {"type": "string", "maxLength": 200, "pattern": r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$",
                     "description": "hook: 'module:function' called as function(t, state) -> number"},
    },
}

FAULT: Dict[str, Any] = {
    "type": "object",
    "required": ["kind"],
    "additionalProperties": False,
    "properties": {
        "kind": {"enum": list(KINDS)},
        "bus": {"type": "string", "maxLength": 64, "description": "the bus's name (default: every bus)"},
        "node": {"oneOf": [{"type": "integer", "minimum": 0, "maximum": 255}, {"const": "all"}],
                 "description": "a node address, or 'all' (default)"},
        "probability": {"type": "number", "minimum": 0, "maximum": 1, "description": "default 1"},
        "ms": {"type": "number", "minimum": 0, "maximum": 60000,
               "description": "late_reply: the delay; split: the gap between the pieces (default 5)"},
        "rate": {"type": "number", "minimum": 0, "maximum": 1,
                 "description": "bit_errors, byte_drops: per byte (default 0.05)"},
        "word": {"type": "integer", "minimum": 1, "maximum": 65535,
                 "description": "error_reply: the error word's bits the node reports (default 1)"},
        "seed": {"type": "integer", "description": "seed of the probability and garbage draws"},
        "at": {"type": "number", "minimum": 0, "maximum": MAX_SCHEDULE_S,
               "description": "seconds after the sim starts when it takes effect (default 0)"},
        "for": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_SCHEDULE_S,
                "description": "seconds in force (then it ends; with every: in each period)"},
        "every": {"type": "number", "exclusiveMinimum": 0, "maximum": MAX_SCHEDULE_S,
                  "description": "a period: in force 'for' seconds of each (needs for)"},
        "direction": {"enum": list(DIRECTIONS),
                      "description": "bit_errors, byte_drops: damage the node's replies (default) or "
                                     "the requests it hears (a damaged request is not executed)"},
    },
}

_COMMON_NODE: Dict[str, Any] = {
    "address": {"type": "integer", "minimum": 0, "maximum": 255, "description": "the node's address"},
    "range": {"type": "array", "minItems": 2, "maxItems": 2, "items": {"type": "integer", "minimum": 0,
              "maximum": 255}, "description": "[first, last]: one node per address (instead of address)"},
    "name": {"type": "string", "maxLength": 64, "description": "a label for status"},
}


def _protocol_names() -> List[str]:
    from ._plugins import simulated

    return simulated()


def _bus_schema(name: str) -> Dict[str, Any]:
    from ._plugins import plugin

    node = {"type": "object", "additionalProperties": False,
            "properties": {**_COMMON_NODE, **plugin(name).NODE_PROPERTIES}}
    return {
        "type": "object",
        "required": ["protocol", "node"],
        "additionalProperties": False,
        "properties": {
            "protocol": {"const": name},
            "name": {"type": "string", "maxLength": 64, "pattern": r"^[A-Za-z0-9_.-]+$",
                     "description": "the bus's name (default busN): faults and status use it"},
            "baud": {"type": "integer", "minimum": 1, "maximum": 10_000_000,
                     "description": "line speed of the bus's ports (default: the protocol's)"},
            "port": {"type": "string", "maxLength": 4096,
                     "description": "an existing port: device path or tcp:// / rfc2217:// URL"},
            "virtual": {"type": "object", "additionalProperties": False,
                        "description": "a new paced virtual bus; port0 is left free for your master",
                        "properties": {
                            "link_dir": {"type": "string", "maxLength": 4096,
                                         "description": "directory of the port symlinks port0.. "
                                         "(default: a private temporary one)"},
                            "baud": {"type": "integer", "minimum": 0, "maximum": 10_000_000,
                                     "description": "pacing rate (default: the bus's baud; 0: unpaced)"},
                            "capture": {"type": "string", "maxLength": 4096,
                                        "description": "record every byte of the bus in this file "
                                        "(docs/vbus.md format)"}}},
            "node": {"type": "array", "minItems": 1, "maxItems": MAX_NODES, "items": node},
        },
    }


def build_schema() -> Dict[str, Any]:
    """The whole schema (the protocol plug-ins' node keys included)."""
    names = _protocol_names()
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": "https://libfap.invalid/fap-sim.schema.json",
        "title": "fap sim configuration",
        "type": "object",
        "additionalProperties": False,
        "required": ["bus"],
        "properties": {
            "sim": {"type": "object", "additionalProperties": False,
                    "description": "the seed and the clock", "properties": {
                "seed": {"type": "integer", "description": "seed of every random draw (default 0)"},
                "clock": {"enum": ["wall", "fast"], "description": "time of the generators"},
                "speed": {"type": "number", "minimum": 0.001, "maximum": 1e6,
                          "description": "clock 'fast': simulated seconds per second"},
            }},
            "bus": {"type": "array", "minItems": 1, "maxItems": MAX_BUSES,
                    "description": "the buses, each of one protocol (tables below)",
                    "items": {"oneOf": [{"$ref": f"#/$defs/bus_{n}"} for n in names]}},
            "fault": {"type": "array", "maxItems": MAX_FAULTS, "items": {"$ref": "#/$defs/fault"},
                      "description": "faults active from the start"},
        },
        "$defs": {"generator": GENERATOR, "fault": FAULT, "hex": HEX, "pattern": PATTERN,
                  **{f"bus_{n}": _bus_schema(n) for n in names}},
    }


_SCHEMA: Optional[Dict[str, Any]] = None


def schema() -> Dict[str, Any]:
    global _SCHEMA
    if _SCHEMA is None:
        _SCHEMA = build_schema()
    return _SCHEMA


# -- the validator ------------------------------------------------------------

class Problem:
    """One schema violation: where (a path of keys and indexes) and what."""

    __slots__ = ("path", "message")

    def __init__(self, path: Path, message: str) -> None:
        self.path, self.message = path, message

    def where(self) -> str:
        out = ""
        for p in self.path:
            out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
        return out or "(top level)"

    def __repr__(self) -> str:
        return f"{self.where()}: {self.message}"


_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and v == v
    and v not in (float("inf"), float("-inf")),
    "boolean": lambda v: isinstance(v, bool),
}


def _kind(v: Any) -> str:
    for name in ("boolean", "integer", "number", "string", "array", "object"):
        if _TYPES[name](v):
            return name
    return "null" if v is None else type(v).__name__


def _resolve(s: Dict[str, Any], root: Dict[str, Any]) -> Dict[str, Any]:
    while "$ref" in s:
        ref = s["$ref"]
        assert ref.startswith("#/$defs/")
        s = root["$defs"][ref[len("#/$defs/"):]]
    return s


def validate(value: Any, root: Optional[Dict[str, Any]] = None) -> List[Problem]:
    """Every violation of ``root`` (default :func:`schema`) by ``value``, first found first."""
    root = schema() if root is None else root
    out: List[Problem] = []
    _check(value, root, root, (), out)
    return out


def _check(v: Any, s: Dict[str, Any], root: Dict[str, Any], path: Path, out: List[Problem]) -> None:
    s = _resolve(s, root)
    if "oneOf" in s:
        _one_of(v, s["oneOf"], root, path, out)
        return
    if "const" in s and v != s["const"]:
        out.append(Problem(path, f"must be {s['const']!r}, not {v!r}"))
        return
    if "enum" in s and v not in s["enum"]:
        out.append(Problem(path, f"{v!r} is not one of {', '.join(map(repr, s['enum']))}"))
        return
    t = s.get("type")
    if t is not None and not _TYPES[t](v):
        out.append(Problem(path, f"must be {'an' if t[0] in 'aeiou' else 'a'} {t}, not {_kind(v)} {_short(v)}"))
        return
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        if "minimum" in s and v < s["minimum"]:
            out.append(Problem(path, f"{v} is below the minimum {s['minimum']}"))
        if "maximum" in s and v > s["maximum"]:
            out.append(Problem(path, f"{v} is above the maximum {s['maximum']}"))
    if isinstance(v, str):
        if "maxLength" in s and len(v) > s["maxLength"]:
            out.append(Problem(path, f"longer than {s['maxLength']} characters"))
        elif "pattern" in s and not re.search(s["pattern"], v):
            what = s.get("description", f"the pattern {s['pattern']}")
            out.append(Problem(path, f"{_short(v)} is not {what}"))
    if isinstance(v, list):
        if "maxItems" in s and len(v) > s["maxItems"]:
            out.append(Problem(path, f"{len(v)} items, at most {s['maxItems']} allowed"))
            return
        if "minItems" in s and len(v) < s["minItems"]:
            out.append(Problem(path, f"{len(v)} items, at least {s['minItems']} needed"))
        if "items" in s:
            for i, item in enumerate(v):
                _check(item, s["items"], root, path + (i,), out)
    if isinstance(v, dict):
        props = s.get("properties", {})
        for k in s.get("required", ()):
            if k not in v:
                out.append(Problem(path, f"the key {k!r} is missing"))
        for k, item in v.items():
            if k in props:
                _check(item, props[k], root, path + (k,), out)
            elif s.get("additionalProperties", True) is False:
                known = ", ".join(sorted(props))
                out.append(Problem(path + (k,), f"unknown key {k!r} (known here: {known})"))


def _one_of(v: Any, branches: Sequence[Dict[str, Any]], root: Dict[str, Any], path: Path,
            out: List[Problem]) -> None:
    resolved = [_resolve(b, root) for b in branches]
    # a discriminated union (the buses by "protocol"): the branch the value names
    if isinstance(v, dict):
        for key in ("protocol",):
            consts = [b.get("properties", {}).get(key, {}).get("const") for b in resolved]
            if all(c is not None for c in consts):
                if key not in v:
                    out.append(Problem(path, f"the key {key!r} is missing (one of {', '.join(consts)})"))
                    return
                if v[key] not in consts:
                    out.append(Problem(path + (key,), f"{v[key]!r} is not one of {', '.join(map(repr, consts))}"))
                    return
                _check(v, resolved[consts.index(v[key])], root, path, out)
                return
    results = []
    for b in resolved:
        errs: List[Problem] = []
        _check(v, b, root, path, errs)
        results.append(errs)
    passed = sum(1 for r in results if not r)
    if passed == 1:
        return
    if passed == 0:
        alts = " or ".join(_describe(b) for b in resolved)
        out.append(Problem(path, f"must be {alts}, not {_short(v)}"))
        return
    out.append(Problem(path, "matches more than one alternative"))


def _describe(s: Dict[str, Any]) -> str:
    if "const" in s:
        return repr(s["const"])
    t = s.get("type", "value")
    lo, hi = s.get("minimum"), s.get("maximum")
    return f"{'an' if t[0] in 'aeiou' else 'a'} {t}" + (f" {lo}..{hi}" if lo is not None and hi is not None else "")


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


# -- the reference in docs/sim.md ---------------------------------------------------

def _type_text(s: Dict[str, Any], root: Dict[str, Any]) -> str:
    if "$ref" in s:
        name = s["$ref"].rsplit("/", 1)[-1]
        return {"generator": "generator table", "fault": "fault tables"}.get(
            name, "bus tables" if name.startswith("bus_") else name)
    if "oneOf" in s:
        if all("$ref" in b for b in s["oneOf"]):
            return _type_text(s["oneOf"][0], root)
        return " or ".join(_type_text(b, root) for b in s["oneOf"])
    if "const" in s:
        return f"`{json_text(s['const'])}`"
    if "enum" in s:
        return " \\| ".join(f"`{v}`" for v in s["enum"])
    t = s.get("type", "any")
    if t == "array" and "items" in s:
        item = s["items"]
        t = f"array of {_type_text(item, root) if item.get('type') != 'object' else 'tables'}"
    lo, hi = s.get("minimum"), s.get("maximum")
    if lo is not None or hi is not None:
        t += f" {'' if lo is None else lo}..{'' if hi is None else hi}"
    if "maxItems" in s:
        t += f" (at most {s['maxItems']})"
    return t


def json_text(v: Any) -> str:
    import json
    return json.dumps(v)


def _rows(title: str, s: Dict[str, Any], root: Dict[str, Any], out: List[str]) -> None:
    out.append(f"#### {title}\n")
    out.append("| key | type | required | description |")
    out.append("|---|---|---|---|")
    req = set(s.get("required", ()))
    nested = []
    for k, v in s.get("properties", {}).items():
        desc = v.get("description", "")
        out.append(f"| `{k}` | {_type_text(v, root)} | {'yes' if k in req else ''} | {desc} |")
        if v.get("type") == "object" and "properties" in v:
            nested.append((f"{title} `{k}`", v))
        elif v.get("type") == "array" and v.get("items", {}).get("type") == "object":
            nested.append((f"{title} `{k}` rows", v["items"]))
    out.append("")
    for t, v in nested:
        _rows(t, v, root, out)


def reference_markdown() -> str:
    """The schema as Markdown tables (docs/sim.md holds this text between its markers)."""
    root = schema()
    out: List[str] = []
    _rows("top level", {"properties": root["properties"], "required": root["required"]}, root, out)
    for name in _protocol_names():
        b = root["$defs"][f"bus_{name}"]
        _rows(f"`{name}` bus", {k: v for k, v in b.items() if k != "properties"} |
              {"properties": {k: v for k, v in b["properties"].items() if k != "node"}}, root, out)
        _rows(f"`{name}` node", b["properties"]["node"]["items"], root, out)
    _rows("generator", root["$defs"]["generator"], root, out)
    _rows("fault", root["$defs"]["fault"], root, out)
    return "\n".join(out).rstrip() + "\n"
