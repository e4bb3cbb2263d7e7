"""The installed package: extension built and packaged, CLI reachable."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import fap_py


def test_imported_from_installed_package_not_source_tree() -> None:
    source_pkg = Path(__file__).resolve().parents[2] / "fap_py"
    assert Path(fap_py.__file__).resolve().parent != source_pkg
    assert "site-packages" in Path(fap_py.__file__).resolve().parts


def test_native_extension_reports_core_version() -> None:
    assert fap_py.native_version() == fap_py.__version__


def test_cli_help_lists_subcommands(tmp_path: Path) -> None:
    # cwd outside the source tree: its fap_py/ (no compiled _native) must not shadow the install
    out = subprocess.run([sys.executable, "-m", "fap_py", "--help"], cwd=tmp_path,
                         check=True, capture_output=True, text=True).stdout
    assert "usage: fap" in out
    assert "version" in out


def test_error_hierarchy_is_rooted_in_faperror() -> None:
    import errno

    err = fap_py.errors.error_from_code(-errno.EIO, "write", "/dev/ttyX")
    assert isinstance(err, fap_py.PortError) and isinstance(err, OSError)
    assert err.errno == errno.EIO and "/dev/ttyX" in str(err)
    assert isinstance(fap_py.errors.error_from_code(-10001), fap_py.BusCollisionError)
    assert issubclass(fap_py.InvalidValueError, ValueError)
    assert issubclass(fap_py.FapTimeoutError, TimeoutError)
