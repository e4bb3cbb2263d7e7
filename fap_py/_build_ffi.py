"""Generate the cffi API-mode (out-of-line) C source for fap_py._native.

Run by meson at build time:  python _build_ffi.py OUTPUT.c CDEF...

The cdef files are fed in the order given (fap_py/meson.build lists them
with dependencies first: common, port, vbus, then the protocols), so a later
file may use the types of an earlier one. Each file holds declarations only (cffi cannot parse ``#``
lines or macros) and names the public headers it mirrors on lines of the
form ``// include: fap_port.h``. The generated module compiles those headers,
so cffi checks every declaration against the real C prototypes.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import cffi

INCLUDE_RE = re.compile(r"^//\s*include:\s*(\S+)\s*$", re.M)


def build(output: Path, cdefs: list[Path]) -> None:
    ffi = cffi.FFI()
    includes: list[str] = []
    for path in cdefs:
        text = path.read_text(encoding="utf-8")
        for header in INCLUDE_RE.findall(text):
            if header not in includes:
                includes.append(header)
        ffi.cdef(text)
    source = "".join(f"#include <{h}>\n" for h in includes)
    ffi.set_source("fap_py._native", source)
    ffi.emit_c_code(str(output))


if __name__ == "__main__":
    build(Path(sys.argv[1]), [Path(a) for a in sys.argv[2:]])
