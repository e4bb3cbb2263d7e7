"""mikroC's address range comes from C (include/mikroc_rs485.h), never re-typed."""
from __future__ import annotations

from fap_py import mikroc
from fap_py._native import lib


def test_address_range_is_the_c_headers() -> None:
    assert (mikroc.NODE_MIN, mikroc.NODE_MAX) == (lib.MIKROC_RS485_ADDR_MIN, lib.MIKROC_RS485_ADDR_MAX)
    assert (mikroc.NODE_MIN, mikroc.NODE_MAX) == (0, 255)
