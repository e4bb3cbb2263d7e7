"""Smoke test of an installed fap_py wheel (run by .ci/wheels.sh in a fresh
venv, outside the source tree): the abi3 extension is the one installed, its
libfap answers, and an exec async master and slave (the C engines) complete
transactions on a virtual bus (ptys, the C relay thread); the metadata
carries the project URLs and classifiers.

    python wheel_smoke.py        prints "wheel smoke: N passed" or fails
"""
from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

import fap_py
from fap_py import _native, execasync
from fap_py.vbus import VirtualBus


def main() -> int:
    passed = 0
    native = Path(_native.__file__)
    assert native.name == "_native.abi3.so", f"not the abi3 extension: {native}"
    assert "site-packages" in native.parts, f"not loaded from the install: {native}"
    passed += 1
    version = _native.ffi.string(_native.lib.fap_version_string()).decode()
    assert version == fap_py.__version__, (version, fap_py.__version__)
    passed += 1
    meta = metadata.metadata("fap_py")
    urls = {u.split(",")[0].strip() for u in meta.get_all("Project-URL") or []}
    assert {"Homepage", "Repository", "Documentation", "Issues"} <= urls, urls
    assert "Programming Language :: Python :: 3.9" in (meta.get_all("Classifier") or [])
    assert meta["Keywords"], "no keywords"
    passed += 1
    with VirtualBus(ports=2) as bus:
        slave = execasync.Slave(bus.paths[1], node=5, handler=lambda req: req.data[::-1])
        slave.start()
        try:
            with execasync.Master(bus.paths[0]) as master:
                for payload in (b"\x01\x02\x03", b"\x10\x10abc", b""):
                    assert master.transact(5, payload) == payload[::-1]
                    passed += 1
        finally:
            slave.close()
    print(f"wheel smoke: {passed} passed (python {sys.version.split()[0]}, libfap {version}, {native.name})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
