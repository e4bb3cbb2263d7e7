"""Write the Wireshark pieces shipped in the package: the Lua dissector and
the extcap launcher (docs/monitor.md says where Wireshark looks)."""
from __future__ import annotations

import os
import shlex
import stat
import sys
from importlib import resources
from pathlib import Path
from typing import List

from .._validate import check_path
from ..errors import PortError

EXTCAP_NAME = "fap-monitor-extcap"


def dissector_files() -> List[str]:
    """Names of the shipped .lua files."""
    root = resources.files("fap_py.monitor") / "dissectors"
    return sorted(p.name for p in root.iterdir() if p.name.endswith(".lua"))


def _directory(directory: object) -> Path:
    out = Path(check_path(directory, "directory"))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PortError(exc.errno or 0, exc.strerror, str(out)) from exc
    return out


def write_dissectors(directory: str) -> List[Path]:
    """Copy the Lua dissector(s) into ``directory`` (created if missing).

    PortError (naming the path) when it cannot be written."""
    out = _directory(directory)
    root = resources.files("fap_py.monitor") / "dissectors"
    written = []
    for name in dissector_files():
        target = out / name
        try:
            target.write_bytes((root / name).read_bytes())
        except OSError as exc:
            raise PortError(exc.errno or 0, exc.strerror, str(target)) from exc
        written.append(target)
    return written


def write_extcap(directory: str) -> Path:
    """Write an executable launcher running this interpreter's extcap module."""
    out = _directory(directory)
    target = out / EXTCAP_NAME
    try:
        target.write_text("#!/bin/sh\n# Wireshark extcap for fap monitor (written by fap monitor "
                          "--extcap-dir)\n"
                          f"exec {shlex.quote(sys.executable)} -m fap_py.monitor.extcap \"$@\"\n")
        mode = os.stat(target).st_mode
        os.chmod(target, mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    except OSError as exc:
        raise PortError(exc.errno or 0, exc.strerror, str(target)) from exc
    return target


__all__ = ["dissector_files", "write_dissectors", "write_extcap"]
