#!/usr/bin/env python3
"""Generate libfap's man3 pages: one page per public C function.

    gen_man3.py SOURCE OUTDIR [--version=V] [--includedir=DIR] [--libdir=DIR] [--source=MORE]... HEADER...

(--includedir/--libdir: where the installed headers and library are, as
each page's SYNOPSIS names them; meson passes the install's own.
--source: a component's own entries, man/functions.d/<comp>.txt.)

The prototype and the comment written above it come from the headers
themselves (so a changed signature changes its page); SOURCE
(man/functions.txt) adds what a header comment does not say in man-page
form: the NAME line, RETURN VALUE, ERRORS, EXAMPLE, SEE ALSO, and a
DESCRIPTION where the header has none. Every function of the headers must
have an entry and every entry a function: the build fails otherwise, so a
new function cannot ship without its page.

SOURCE format, one block per function:

    == fapx_open
    open a FAP node (master or slave) on a serial port     <- NAME line
    -- description          (optional: replaces the header comment)
    -- more                 (optional: appended to the header comment)
    -- return
    -- errors               (lines "NAME: text" become a tagged list)
    -- example              (kept as written, in a literal block)
    -- see                  (names; man3 unless "name(N)")

Each --source=MORE (man/functions.d/<component>.txt, one per component
that has one) adds entries in the same format; a function described twice
fails the build. Lines starting "#" outside blocks are comments. A "%% date: YYYY-MM-DD"
line sets the pages' date.
"""
from __future__ import annotations

import re
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

PROTO_RE = re.compile(r"^(?:extern\s+)?([A-Za-z_][\w\s\*]*?[\s\*])(\w+)\s*\(([^;]*)\)\s*;", re.S)


@dataclass
class Function:
    name: str
    header: str
    prototype: str
    comment: str          # the comment block written above it ("" if none)


@dataclass
class Entry:
    name: str
    summary: str
    sections: Dict[str, str] = field(default_factory=dict)


def parse_header(path: Path) -> List[Function]:
    """Prototypes at file scope, each with its doc comment: the comment block
    that precedes its group (prototypes and #defines with no blank line
    between them), plus a comment that follows it on the same line."""
    text = path.read_text(encoding="utf-8")
    events = []                       # (start, end, kind, text)
    for m in re.finditer(r"/\*.*?\*/", text, re.S):
        events.append((m.start(), m.end(), "comment", m.group(0)))
    code = re.sub(r"/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S)
    code = re.sub(r"(?m)^[ \t]*#(?:[^\n]*\\\n)*[^\n]*", lambda m: re.sub(r"[^\n]", " ", m.group(0)), code)
    code = code.replace('extern "C" {', " " * len('extern "C" {'))
    depth, start = 0, None
    for i, ch in enumerate(code):
        if start is None and not ch.isspace() and ch != "}" or (start is None and ch == "}" and depth > 0):
            start = i
        if ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
            if depth < 0:             # the closing brace of extern "C"
                depth, start = 0, None
        elif ch == ";" and depth == 0 and start is not None:
            events.append((start, i + 1, "stmt", code[start:i + 1]))
            start = None
    for m in re.finditer(r"(?m)^[ \t]*#define\b[^\n]*", text):
        events.append((m.start(), m.end(), "define", ""))
    events.sort()
    out: List[Function] = []
    comment, last_end, last_fn = "", 0, None
    for s0, e0, kind, body in events:
        gap = text[last_end:s0]
        same_line = "\n" not in gap
        if re.search(r"\n[ \t]*\n", gap):
            comment = ""
        if kind == "comment":
            if same_line and last_fn is not None:      # trailing: belongs to that prototype
                last_fn.comment = (last_fn.comment + "\n\n" + clean_comment(body)).strip()
            elif not same_line or last_end == 0:
                comment = clean_comment(body)
            last_end = e0
            continue
        last_fn = None
        if kind == "stmt":
            decl = " ".join(body.split())
            m = PROTO_RE.match(decl)
            if m and not decl.startswith(("typedef", "struct", "enum")):
                last_fn = Function(m.group(2), path.name, decl, comment)
                out.append(last_fn)
            else:
                comment = ""
        last_end = e0
    return out


def clean_comment(block: str) -> str:
    """The text of a /* ... */ block without its decoration."""
    if not block:
        return ""
    body = block.strip()
    body = re.sub(r"^/\*+", "", body)
    body = re.sub(r"\*+/$", "", body)
    lines = [re.sub(r"^\s*\* ?", "", ln) if ln.lstrip().startswith("*") else ln.strip()
             for ln in body.splitlines()]
    # drop a leading "---- name ----" banner line
    lines = [ln for ln in lines if not re.match(r"^-+\s.*-+$", ln.strip())]
    return "\n".join(lines).strip()


def parse_source(path: Path) -> tuple[str, Dict[str, Entry]]:
    date = "1970-01-01"
    entries: Dict[str, Entry] = {}
    entry: Optional[Entry] = None
    section: Optional[str] = None
    buf: List[str] = []

    def flush() -> None:
        if entry is not None and section is not None:
            entry.sections[section] = "\n".join(buf).strip("\n")

    for raw in path.read_text(encoding="utf-8").splitlines():
        if raw.startswith("%% date:"):
            date = raw.split(":", 1)[1].strip()
        elif raw.startswith("== "):
            flush()
            name = raw[3:].strip()
            if name in entries:
                raise SystemExit(f"{path}: {name} twice")
            entry, section, buf = Entry(name, ""), None, []
            entries[name] = entry
        elif raw.startswith("-- ") and entry is not None:
            flush()
            section, buf = raw[3:].strip(), []
        elif entry is not None and section is None:
            if raw.strip() and not entry.summary:
                entry.summary = raw.strip()
        elif entry is not None:
            buf.append(raw)
        elif raw.strip() and not raw.startswith("#"):
            raise SystemExit(f"{path}: text outside an entry: {raw!r}")
    flush()
    return date, entries


def esc(text: str) -> str:
    """Escape roff specials in running text."""
    return text.replace("\\", "\\e")


def line_safe(line: str) -> str:
    return "\\&" + line if line.startswith((".", "'")) else line


def paragraphs(text: str) -> List[str]:
    """roff for text: blank lines split paragraphs; a paragraph whose lines
    (after the first) are indented by two or more spaces, or that holds
    code-like lines, is kept as written."""
    out: List[str] = []
    for para in re.split(r"\n\s*\n", text.strip()):
        lines = para.splitlines()
        literal = any(ln.startswith("  ") for ln in lines) or any(
            ln.rstrip().endswith((";", "{", "}", "};")) for ln in lines)
        if literal:
            out.append(".PP\n.nf\n" + "\n".join(line_safe(esc(ln)) for ln in lines) + "\n.fi")
        else:
            out.append(".PP\n" + fill(" ".join(ln.strip() for ln in lines)))
    return out


def fill(text: str) -> str:
    """Running text as roff lines of at most 78 characters."""
    lines = textwrap.wrap(esc(text), 78, break_long_words=False, break_on_hyphens=False)
    return "\n".join(line_safe(ln) for ln in lines)


TAG = r"[A-Z_][A-Z0-9_, .]*"


def tagged(text: str) -> List[str]:
    """"NAME: text" lines as a tagged list (.TP), other text as paragraphs."""
    out = []
    for para in re.split(r"\n(?=" + TAG + r":\s)", text.strip()):
        m = re.match(r"^(" + TAG + r"):\s+(.*)$", para, re.S)
        if m:
            out.append('.TP\n.B "' + esc(m.group(1)) + '"\n' + fill(" ".join(m.group(2).split())))
        else:
            out.extend(paragraphs(para))
    return out


def see_also(names: str, self_name: str) -> str:
    refs = []
    for n in names.split():
        n = n.strip(",")
        if n == self_name or not n:
            continue
        m = re.match(r"^([\w.-]+)\((\d)\)$", n)
        refs.append((m.group(1), m.group(2)) if m else (n, "3"))
    refs.append(("libfap", "7"))
    seen = []
    for r in refs:
        if r not in seen:
            seen.append(r)
    return ",\n".join(f".BR {esc(n)} ({s})" for n, s in seen)


def wrap_prototype(proto: str) -> List[str]:
    """Split a long prototype after its commas, continuation lines indented
    under the opening parenthesis."""
    proto = re.sub(r"^extern\s+", "", proto)
    proto = re.sub(r"\s+\(", "(", proto).replace(" ;", ";").replace(" )", ")")
    if len(proto) <= 78:
        return [proto]
    indent = " " * (proto.index("(") + 1)
    lines, cur = [], ""
    for piece in re.split(r"(?<=,) ", proto):
        if cur and len(cur) + 1 + len(piece) > 78:
            lines.append(cur)
            cur = indent + piece
        else:
            cur = f"{cur} {piece}" if cur else piece
    return lines + [cur]


#: where the pages say the headers and the library are: the install's own
#: directories (meson passes --includedir= and --libdir=), these by default
DEFAULT_PATHS = {"includedir": "/usr/local/include/libfap", "libdir": "/usr/local/lib"}


def render(fn: Function, entry: Entry, date: str, version: str,
           paths: Optional[Dict[str, str]] = None) -> str:
    s = entry.sections
    paths = paths or DEFAULT_PATHS
    parts = [
        f'.TH {fn.name.upper()} 3 {date} "libfap {version}" "libfap Manual"',
        ".SH NAME",
        fill(f"{fn.name} \\- {entry.summary}").replace("\\e-", "\\-", 1),
        ".SH SYNOPSIS",
        ".nf",
        f".B #include <{fn.header}>",
        ".PP",
        *(f"\\fB{esc(ln)}\\fP" for ln in wrap_prototype(fn.prototype)),
        ".fi",
        ".PP",
        "Compile and link with either of:",
        ".PP",
        ".RS",
        ".nf",
        "cc app.c $(pkg-config \\-\\-cflags \\-\\-libs fap)",
        f"cc \\-I{esc(paths['includedir'])} app.c \\-L{esc(paths['libdir'])} \\-lfap \\-lpthread \\-lrt",
        ".fi",
        ".RE",
        ".SH DESCRIPTION",
    ]
    desc = s.get("description") or fn.comment
    if not desc:
        raise SystemExit(f"{fn.name}: no header comment and no '-- description'")
    body = paragraphs(desc)
    if s.get("more"):
        body += paragraphs(s["more"])
    body[0] = body[0].removeprefix(".PP\n")
    parts += body
    if fn.prototype.startswith("void ") and not fn.prototype.startswith("void *"):
        ret = s.get("return", "None: the function returns nothing.")
    else:
        if "return" not in s:
            raise SystemExit(f"{fn.name}: returns a value but has no '-- return'")
        ret = s["return"]
    ret_parts = tagged(ret)
    ret_parts[0] = ret_parts[0].removeprefix(".PP\n")   # no paragraph break right after .SH
    parts += [".SH RETURN VALUE"] + ret_parts
    if s.get("errors"):
        parts += [".SH ERRORS"] + tagged(s["errors"])
    if s.get("example"):
        parts += [".SH EXAMPLE", ".nf"] + [line_safe(esc(ln)) for ln in s["example"].splitlines()] + [".fi"]
    parts += [".SH SEE ALSO", see_also(s.get("see", ""), fn.name)]
    return "\n".join(parts) + "\n"


def main(argv: List[str]) -> int:
    if argv and argv[0] == "--count":     # how many pages the headers call for
        print(sum(len(parse_header(Path(h))) for h in argv[1:]))
        return 0
    source, outdir, *headers = argv
    version = "0"
    paths = dict(DEFAULT_PATHS)
    more: List[str] = []
    while headers and headers[0].startswith("--"):
        key, _, value = headers.pop(0)[2:].partition("=")
        if key == "version":
            version = value
        elif key == "source":
            more.append(value)
        elif key in paths and value.startswith("/"):
            paths[key] = value
        else:
            raise SystemExit(f"gen_man3.py: unknown option or not an absolute path: --{key}={value}")
    date, entries = parse_source(Path(source))
    for extra in more:            # a component's own entries (man/functions.d/<comp>.txt)
        _, got = parse_source(Path(extra))
        twice = sorted(entries.keys() & got.keys())
        if twice:
            raise SystemExit(f"{extra}: entries already in {source}: {twice}")
        entries.update(got)
        source += f", {extra}"
    functions: List[Function] = []
    for h in headers:
        functions += parse_header(Path(h))
    names = {f.name for f in functions}
    missing = sorted(names - entries.keys())
    extra = sorted(entries.keys() - names)
    if missing or extra:
        raise SystemExit(f"{source}: no entry for {missing}; entries without a function {extra}")
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.3"):           # a removed function loses its page
        old.unlink()
    for fn in functions:
        (out / f"{fn.name}.3").write_text(render(fn, entries[fn.name], date, version, paths), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
