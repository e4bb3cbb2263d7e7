"""fap_py.port.port_kind: what a port string is, answered by the C core's one
parse (fap_port_kind), and the places that used to guess now agree with it."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import pytest

from fap_py.errors import InvalidTypeError, InvalidValueError
from fap_py.port import PORT_KINDS, is_network, port_kind

ROWS = [
    ("/dev/ttyUSB0", "device"),
    ("/dev/pts/7", "device"),
    ("tcp://192.0.2.7:4001", "tcp"),
    ("tcp://pi.local:2000?rtt_ms=5", "tcp"),
    ("rfc2217://[::1]:4001?connect_ms=100&option_ms=0", "rfc2217"),
    ("socket://127.0.0.1:7000", "other"),
    ("loop://", "other"),
    ("spy://COM1", "other"),
    ("tcp://host", "invalid"),
    ("tcp://host:0", "invalid"),
    ("rfc2217://host:1?x=1", "invalid"),
]


@pytest.mark.parametrize("path,kind", ROWS)
def test_port_kind(path: str, kind: str) -> None:
    assert port_kind(path) == kind
    assert port_kind(os.fsencode(path)) == kind
    assert kind in PORT_KINDS
    assert is_network(path) == (kind in ("tcp", "rfc2217"))


def test_path_like_and_bad_type() -> None:
    assert port_kind(Path("/dev/ttyS0")) == "device"
    with pytest.raises(InvalidTypeError):
        port_kind(3)  # type: ignore[arg-type]


class _LyingPath:
    """An os.PathLike whose __fspath__ returns no path."""

    def __fspath__(self) -> object:
        return 5


@pytest.mark.parametrize("fn", [port_kind, is_network])
@pytest.mark.parametrize("bad", [None, 3, 1.5, True, object(), [b"/dev/x"], _LyingPath()])
def test_not_a_path_is_a_type_error(fn: object, bad: object) -> None:
    with pytest.raises(InvalidTypeError, match="port must be a path or URL string"):
        fn(bad)  # type: ignore[operator]


@pytest.mark.parametrize("fn", [port_kind, is_network])
@pytest.mark.parametrize("bad", ["", b"", "/dev/tty\0S0", b"tcp://h:1\0", Path("/dev/a\0b")])
def test_empty_or_nul_is_refused(fn: object, bad: object) -> None:
    """No device nor URL is empty or holds a NUL: refused, not answered "device"/"invalid"."""
    with pytest.raises(InvalidValueError, match="empty|NUL"):
        fn(bad)  # type: ignore[operator]


@pytest.mark.parametrize("path,kind", ROWS)
def test_g485_transport_routes_by_kind(path: str, kind: str) -> None:
    """g485 hands pyserial only the schemes the C port layer does not open."""
    from fap_py.g485.transport import _is_url

    assert _is_url(path) == (kind == "other")


@pytest.mark.parametrize("path", [p for p, k in ROWS if k == "other"])
def test_g485_cli_no_line_options_for_pyserial(path: str) -> None:
    """`fap g485 --port socket://...`: pyserial's URL carries its own line options."""
    from fap_py.commands.protocols import g485

    assert g485._rs485(argparse.Namespace(port=path)) is None
