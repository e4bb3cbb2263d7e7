"""The C port layer through the cffi extension, on real ptys."""
from __future__ import annotations

import errno
import os
from collections.abc import Iterator

import pytest

from fap_py._native import ffi, lib


@pytest.fixture
def pty() -> Iterator[tuple[int, str]]:
    """A pty pair: the master fd (the far end) and the slave path."""
    master, slave = os.openpty()
    name = os.ttyname(slave)
    os.close(slave)
    yield master, name
    os.close(master)


def open_port(path: str, mode: int = lib.FAP_RS485_NONE, **fields: int) -> tuple[int, object]:
    """fap_port_open with defaults plus the given option fields."""
    o = ffi.new("fap_port_options *")
    lib.fap_port_options_init(o)
    o.rs485_mode = mode
    for k, v in fields.items():
        setattr(o, k, v)
    pp = ffi.new("fap_port **")
    rc = lib.fap_port_open(pp, path.encode(), o)
    return rc, pp[0] if rc == 0 else None


def test_auto_on_pty_falls_back_to_none(pty: tuple[int, str]) -> None:
    _, name = pty
    rc, p = open_port(name, lib.FAP_RS485_AUTO)
    assert rc == 0
    try:
        assert lib.fap_port_mode(p) == lib.FAP_RS485_NONE
        assert lib.fap_port_auto_errno(p) == errno.ENOTTY
        assert lib.fap_port_kernel_rs485(p, ffi.NULL, ffi.NULL, ffi.NULL) == -errno.ENOTTY
    finally:
        lib.fap_port_close(p)


@pytest.mark.parametrize("mode", ["FAP_RS485_KERNEL", "FAP_RS485_SOFT_RTS"])
def test_explicit_mode_refused_by_pty(pty: tuple[int, str], mode: str) -> None:
    _, name = pty
    rc, _ = open_port(name, getattr(lib, mode))
    assert rc == -errno.ENOTTY
    assert ffi.string(lib.fap_port_strerror(rc)) == os.strerror(errno.ENOTTY).encode()


def test_round_trip_and_busy(pty: tuple[int, str]) -> None:
    master, name = pty
    rc, p = open_port(name)
    assert rc == 0
    try:
        assert open_port(name)[0] == -errno.EBUSY
        assert lib.fap_port_write(p, b"\x00ping\xff", 6) == 6
        got = b""
        while len(got) < 6:
            got += os.read(master, 6 - len(got))
        assert got == b"\x00ping\xff"
        os.write(master, b"pong")
        buf = ffi.new("char[16]")
        deadline = lib.fap_port_now_ns() + 2_000_000_000
        n = lib.fap_port_read(p, buf, 16, deadline)
        assert n > 0
        assert b"pong".startswith(ffi.buffer(buf, n)[:])
        stats = ffi.new("fap_port_stats *")
        lib.fap_port_get_stats(p, stats)
        assert stats.tx_bytes == 6
    finally:
        lib.fap_port_close(p)


def test_bad_baud_and_missing_device(pty: tuple[int, str]) -> None:
    _, name = pty
    assert open_port(name, baud=12345)[0] == -errno.EINVAL
    assert open_port("/nonexistent/ttyFAP9")[0] == -errno.ENOENT


@pytest.mark.parametrize("err", [errno.EIO, errno.ENXIO, errno.ENODEV, errno.EPIPE, errno.EBADF])
def test_gone_codes_come_from_c(err: int) -> None:
    """fap_py names a vanished device by the C core's one list (fap_port_error_is_gone)."""
    from fap_py.errors import PortGoneError, error_from_code

    assert lib.fap_port_error_is_gone(-err) == 1
    exc = error_from_code(-err, "write", "/dev/ttyX")
    assert isinstance(exc, PortGoneError)
    assert exc.errno == err


def test_other_codes_are_not_gone() -> None:
    from fap_py.errors import PortError, PortGoneError, error_from_code

    for err in (errno.EPERM, errno.ENOTTY, errno.EAGAIN):
        assert lib.fap_port_error_is_gone(-err) == 0
        exc = error_from_code(-err, "write", "/dev/ttyX")
        assert isinstance(exc, PortError) and not isinstance(exc, PortGoneError)
