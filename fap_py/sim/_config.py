"""Reading a ``fap sim`` config: TOML, JSON or YAML, checked against :mod:`.schema`.

:func:`load` returns the parsed dict after the schema and the semantic checks (address
ranges, hex, hooks that import); every error is a :class:`SimConfigError` whose one line
names the file and, where the format has lines, the line (``site.toml:12: bus[0].node[3].address:
300 is above the maximum 254``). tomllib and json report no line for a value that parses but is
wrong, so the line of a key is found by a scan of the file (:func:`line_of`).
"""
from __future__ import annotations

import json
import os
import re
from typing import Any, Dict, List, Optional, Tuple, Union

from .._validate import check_path
from ..errors import FapError, InvalidTypeError, InvalidValueError
from ._faults import PARAMS
from ._generators import resolve_hook
from ._schema import Path, Problem, validate

__all__ = ["MAX_CONFIG_BYTES", "SimConfigError", "load", "loads", "line_of"]

#: the largest config file read
MAX_CONFIG_BYTES = 1 << 20
FORMATS = ("toml", "json", "yaml")


class SimConfigError(InvalidValueError):
    """A config that cannot run: one line naming the file and line (exit 2)."""

    def __init__(self, file: str, line: Optional[int], message: str) -> None:
        self.file, self.line, self.message = file, line, message
        super().__init__(f"{file}:{line}: {message}" if line else f"{file}: {message}")


def _format(path: str, text: Optional[str]) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext in (".toml",):
        return "toml"
    if ext in (".json",):
        return "json"
    if ext in (".yaml", ".yml"):
        return "yaml"
    if text is not None and text.lstrip()[:1] in ("{",):
        return "json"
    return "toml"


def load(path: Union[str, "os.PathLike[str]"]) -> Dict[str, Any]:
    """Read, parse and check the config at ``path``."""
    path = check_path(path, "config path")
    try:
        st = os.stat(path)
        if not os.path.isfile(path):
            raise SimConfigError(path, None, "not a regular file")
        if st.st_size > MAX_CONFIG_BYTES:
            raise SimConfigError(path, None, f"{st.st_size} bytes, a config is at most {MAX_CONFIG_BYTES}")
        with open(path, "rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise SimConfigError(path, None, f"cannot read: {exc.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise SimConfigError(path, line, "not UTF-8 text") from None
    return loads(text, path, _format(path, text))


def loads(text: str, name: str = "<config>", fmt: str = "toml") -> Dict[str, Any]:
    """Parse and check config ``text`` in format ``fmt`` ("toml", "json", "yaml")."""
    if not isinstance(text, str):
        raise InvalidTypeError(f"config text must be a str, not {type(text).__name__}")
    if not isinstance(name, str):
        raise InvalidTypeError(f"config name must be a str, not {type(name).__name__}")
    if not isinstance(fmt, str):
        raise InvalidTypeError(f"config format must be a str, not {type(fmt).__name__}")
    if fmt not in FORMATS:
        raise InvalidValueError(f"config format must be one of {', '.join(FORMATS)}, not {fmt!r}")
    if len(text) > MAX_CONFIG_BYTES:
        raise SimConfigError(name, None, f"longer than {MAX_CONFIG_BYTES} characters")
    data = _parse(text, name, fmt)
    if not isinstance(data, dict):
        raise SimConfigError(name, 1, "the config must be a table/object at the top level")
    problems = validate(data)
    if problems:
        _raise(problems[0], text, name, fmt)
    problems = semantic(data)
    if problems:
        _raise(problems[0], text, name, fmt)
    return data


def check_config(data: Any, name: str = "<config>") -> Dict[str, Any]:
    """``data`` if it is a config that passes the checks of :func:`loads` (a dict built in
    Python, or what :func:`load` returned); else the first problem as a SimConfigError."""
    if not isinstance(data, dict):
        raise InvalidTypeError(f"config must be a dict (from fap_py.sim.load/loads), "
                               f"not {type(data).__name__}")
    for check in (validate, semantic):
        try:
            problems = check(data)
        except FapError:
            raise
        except Exception as exc:  # a structure the checks were not written for
            raise SimConfigError(name, None, f"not a config: {type(exc).__name__}: {exc}") from None
        if problems:
            raise SimConfigError(name, None, f"{problems[0].where()}: {problems[0].message}")
    return data


def _raise(p: Problem, text: str, name: str, fmt: str) -> None:
    raise SimConfigError(name, line_of(text, fmt, p.path), f"{p.where()}: {p.message}")


def _parse(text: str, name: str, fmt: str) -> Any:
    if fmt == "toml":
        import tomllib

        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            msg = str(exc)
            m = re.search(r"\(at line (\d+), column \d+\)", msg)
            line = int(m.group(1)) if m else None
            if m:
                msg = msg[:m.start()].strip()
            elif "end of document" in msg:
                line = text.count("\n") + 1
            raise SimConfigError(name, line, f"TOML: {msg}") from None
    if fmt == "json":
        try:
            return json.loads(text, parse_constant=_no_constant)
        except json.JSONDecodeError as exc:
            raise SimConfigError(name, exc.lineno, f"JSON: {exc.msg}") from None
        except (ValueError, RecursionError) as exc:
            raise SimConfigError(name, None, f"JSON: {exc}") from None
    if fmt == "yaml":
        return _parse_yaml(text, name)
    raise SimConfigError(name, None, f"unknown config format {fmt!r} (toml, json, yaml)")


def _no_constant(word: str) -> Any:
    raise ValueError(f"{word} is not a JSON number")


def _parse_yaml(text: str, name: str) -> Any:
    try:
        import yaml  # type: ignore[import-untyped, unused-ignore]
    except ImportError:
        raise SimConfigError(name, None, "a YAML config needs PyYAML (pip install pyyaml), "
                             "or write it as TOML or JSON") from None
    try:
        for ev in yaml.parse(text, Loader=yaml.SafeLoader):
            anchor = getattr(ev, "anchor", None)
            if isinstance(ev, yaml.AliasEvent) or anchor:
                raise SimConfigError(name, ev.start_mark.line + 1,
                                     "YAML anchors and aliases are not allowed in a sim config")
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise SimConfigError(name, line, f"YAML: {getattr(exc, 'problem', None) or exc}") from None


# -- semantic checks (after the schema) ---------------------------------------------

def semantic(data: Dict[str, Any]) -> List[Problem]:
    """What the schema cannot say: addresses in the protocol's range and not twice, hex that
    parses, a port or a virtual bus, hooks that import."""
    from ._plugins import plugin

    out: List[Problem] = []
    names = set()
    for b, bus in enumerate(data.get("bus", ())):
        name = bus.get("name", f"bus{b}")
        if name in names:
            out.append(Problem(("bus", b, "name"), f"the bus name {name!r} is used twice"))
        names.add(name)
        if "port" in bus and "virtual" in bus:
            out.append(Problem(("bus", b, "port"), "a bus has a port or a virtual bus, not both"))
        proto = plugin(bus["protocol"])
        seen: Dict[int, int] = {}
        for n, node in enumerate(bus["node"]):
            where = ("bus", b, "node", n)
            addrs, problem = node_addresses(node, proto, where)
            if problem:
                out.append(problem)
                continue
            for a in addrs:
                if a in seen:
                    out.append(Problem(where, f"address {a} is already node[{seen[a]}]'s"))
                    break
                seen[a] = n
            out.extend(proto.check_node(node, where))
            out.extend(check_generators(node, where))
        per_node = getattr(proto, "PORT_PER_NODE", False)
        if per_node and "port" in bus and len(seen) > 1:
            out.append(Problem(("bus", b, "port"), f"a {proto.NAME} bus on an existing port holds one "
                               "node (each has its own port): use a virtual bus"))
        if per_node and "port" not in bus:
            from ..vbus import MAX_PORTS
            if len(seen) + 1 > MAX_PORTS:
                out.append(Problem(("bus", b, "node"), f"{len(seen)} {proto.NAME} nodes need {len(seen) + 1} "
                                   f"ports, a virtual bus has at most {MAX_PORTS}"))
    for f, fault in enumerate(data.get("fault", ())):
        if fault.get("bus") is not None and fault["bus"] not in names:
            out.append(Problem(("fault", f, "bus"), f"no bus is named {fault['bus']!r}"))
        if fault["kind"] == "late_reply" and "ms" not in fault:
            out.append(Problem(("fault", f), "late_reply needs 'ms'"))
        for key in ("ms", "rate", "word"):
            if key in fault and PARAMS.get(fault["kind"], ("",))[0] != key:
                out.append(Problem(("fault", f, key), f"{key} is not a parameter of {fault['kind']}"))
        if "every" in fault and not ("for" in fault and fault["for"] < fault["every"]):
            out.append(Problem(("fault", f, "every"), "every needs for, shorter than every"))
    return out


def node_addresses(node: Dict[str, Any], proto: Any, where: Path) -> Tuple[List[int], Optional[Problem]]:
    """The addresses of one node entry (``address``, or every address of ``range``)."""
    lo, hi = proto.ADDRESS_MIN, proto.ADDRESS_MAX
    if ("address" in node) == ("range" in node):
        return [], Problem(where, "a node has 'address' or 'range' (one of them)")
    if "address" in node:
        addrs = [node["address"]]
        key: Path = where + ("address",)
    else:
        first, last = node["range"]
        if first > last:
            return [], Problem(where + ("range",), f"[{first}, {last}]: first is above last")
        addrs = list(range(first, last + 1))
        key = where + ("range",)
    for a in addrs:
        if not lo <= a <= hi or a in getattr(proto, "ADDRESS_RESERVED", ()):
            reserved = getattr(proto, "ADDRESS_RESERVED", ())
            extra = f", not {', '.join(map(str, reserved))}" if reserved else ""
            return [], Problem(key, f"address {a} is not a node address of {proto.NAME} ({lo}..{hi}{extra})")
    return addrs, None


def check_generators(node: Dict[str, Any], where: Path) -> List[Problem]:
    """Every generator spec in a node (any key whose value is a table with ``kind``)."""
    out: List[Problem] = []

    def walk(v: Any, path: Path) -> None:
        if isinstance(v, dict):
            if "kind" in v and path[-1] in ("value", "generator"):
                out.extend(check_generator(v, path))
            for k, item in v.items():
                walk(item, path + (k,))
        elif isinstance(v, list):
            for i, item in enumerate(v):
                walk(item, path + (i,))

    walk(node, where)
    return out


def check_generator(g: Dict[str, Any], where: Path) -> List[Problem]:
    kind = g.get("kind")
    if kind == "const" and "value" not in g:
        return [Problem(where, "a const generator needs 'value'")]
    if kind == "steps" and not g.get("values"):
        return [Problem(where, "a steps generator needs a non-empty 'values' list")]
    if kind == "hook":
        if "function" not in g:
            return [Problem(where, "a hook generator needs 'function' (module:function)")]
        try:
            resolve_hook(g["function"])
        except InvalidValueError as exc:
            return [Problem(where + ("function",), str(exc))]
    return []


# -- where a key is in the file ----------------------------------------------------

def line_of(text: str, fmt: str, path: Path) -> Optional[int]:
    """The line of ``path`` (keys and indexes) in the file ``text``, or of its nearest
    enclosing key found; None when nothing of it is found."""
    try:
        if fmt == "toml":
            table = _toml_lines(text)
        elif fmt == "json":
            table = _json_lines(text)
        elif fmt == "yaml":
            table = _yaml_lines(text)
        else:
            return None
    except Exception:   # a scan is best effort: the error itself still names the key
        return None
    for n in range(len(path), 0, -1):
        line = table.get(tuple(path[:n]))
        if line is not None:
            return line
    return None


_HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r'^\s*((?:"[^"]*"|\'[^\']*\'|[A-Za-z0-9_-]+)(?:\s*\.\s*(?:"[^"]*"|\'[^\']*\'|[A-Za-z0-9_-]+))*)\s*=')


def _split_key(key: str) -> List[str]:
    parts = re.findall(r'"([^"]*)"|\'([^\']*)\'|([A-Za-z0-9_-]+)', key)
    return [a or b or c for a, b, c in parts]


def _toml_lines(text: str) -> Dict[Path, int]:
    """Path -> line of the TOML scan: ``[[a.b]]`` headers count their array's items (an
    item of ``a.b`` restarts when a new ``a`` item begins), ``key =`` lines under them;
    inline tables and arrays are found by their key's line."""
    out: Dict[Path, int] = {}
    counts: Dict[Path, int] = {}      # array of tables (by resolved parent path) -> items
    current: Path = ()
    arrays: Dict[Tuple[str, ...], Path] = {}   # dotted name -> resolved path of its last item
    in_multiline = False
    for lineno, line in enumerate(text.splitlines(), start=1):
        if in_multiline:
            if '"""' in line or "'''" in line:
                in_multiline = False
            continue
        m = _HEADER.match(line)
        if m and not _KEY.match(line):
            names = _split_key(m.group(2))
            resolved: Path = ()
            for i, nm in enumerate(names):
                resolved = resolved + (nm,)
                last = arrays.get(tuple(names[:i + 1]))
                if last is not None and i < len(names) - 1:
                    resolved = last
            if m.group(1) == "[[":
                idx = counts.get(resolved, 0)
                counts[resolved] = idx + 1
                item = resolved + (idx,)
                arrays[tuple(names)] = item
                # a new item forgets the nested arrays' items of the old one
                for k in [k for k in arrays if len(k) > len(names) and k[:len(names)] == tuple(names)]:
                    del arrays[k]
                out.setdefault(resolved, lineno)
                out[item] = lineno
                current = item
            else:
                out.setdefault(resolved, lineno)
                current = resolved
            continue
        km = _KEY.match(line)
        if km:
            path = current + tuple(_split_key(km.group(1)))
            out.setdefault(path, lineno)
            rest = line[km.end():]
            if rest.count('"""') == 1 or rest.count("'''") == 1:
                in_multiline = True
    return out


def _json_lines(text: str) -> Dict[Path, int]:
    """Path -> line of each value in a JSON document (a small structural scan)."""
    from json.decoder import scanstring  # type: ignore[attr-defined]

    out: Dict[Path, int] = {}
    pos = 0
    n = len(text)
    ws = re.compile(r"[ \t\n\r]*")

    def line(p: int) -> int:
        return text.count("\n", 0, p) + 1

    def skip(p: int) -> int:
        return ws.match(text, p).end()  # type: ignore[union-attr]

    def value(p: int, path: Path, depth: int) -> int:
        if depth > 200:
            raise ValueError("too deep")
        p = skip(p)
        out.setdefault(path, line(p))
        c = text[p] if p < n else ""
        if c == "{":
            p = skip(p + 1)
            if text[p] == "}":
                return p + 1
            while True:
                p = skip(p)
                key, p = scanstring(text, p + 1)
                p = skip(p)
                assert text[p] == ":"
                kp = skip(p + 1)
                out.setdefault(path + (key,), line(kp))
                p = skip(value(p + 1, path + (key,), depth + 1))
                if text[p] == ",":
                    p += 1
                    continue
                return p + 1
        if c == "[":
            p = skip(p + 1)
            if text[p] == "]":
                return p + 1
            i = 0
            while True:
                p = skip(value(p, path + (i,), depth + 1))
                i += 1
                if text[p] == ",":
                    p += 1
                    continue
                return p + 1
        if c == '"':
            return scanstring(text, p + 1)[1]
        m = re.compile(r"[^,\]\}\s]+").match(text, p)
        return m.end() if m else p + 1

    value(pos, (), 0)
    return out


def _yaml_lines(text: str) -> Dict[Path, int]:
    import yaml  # type: ignore[import-untyped, unused-ignore]

    out: Dict[Path, int] = {}

    def walk(node: Any, path: Path) -> None:
        out.setdefault(path, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                out.setdefault(path + (k.value,), k.start_mark.line + 1)
                walk(v, path + (k.value,))
        elif isinstance(node, yaml.SequenceNode):
            for i, v in enumerate(node.value):
                walk(v, path + (i,))

    root = yaml.compose(text, Loader=yaml.SafeLoader)
    if root is not None:
        walk(root, ())
    return out
