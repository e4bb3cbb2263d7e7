"""RS485 GPIO mode (``FAP_RS485_GPIO``) from Python and the CLI: the
options reach C (``fap_port_options.gpio_chip/gpio_line``), bad ones are
refused before C, and a chip that is not there fails the open with the
OS error. (The line itself is exercised by the C fake-backend tests and,
on a real PL061, by the QEMU suite: this host has no gpiochip.)"""
from __future__ import annotations

import os
import tty
from collections.abc import Iterator

import pytest

from fap_py._native import ffi
from fap_py.errors import InvalidTypeError, InvalidValueError, PortError
from fap_py.port import Port
from fap_py.rs485 import RS485, RS485Mode, port_options


@pytest.fixture
def pty() -> Iterator[str]:
    far, near = os.openpty()
    tty.setraw(far)
    name = os.ttyname(near)
    os.close(near)
    yield name
    os.close(far)


def test_gpio_options_reach_c() -> None:
    po = port_options(115200, RS485(mode=RS485Mode.GPIO, gpio_chip="/dev/gpiochip3", gpio_line=17,
                                    rts_active_high=False, delay_after_send_us=250))
    assert po.rs485_mode == RS485Mode.GPIO == 4
    assert ffi.string(po.gpio_chip) == b"/dev/gpiochip3" and po.gpio_line == 17
    assert po.rts_active_high == 0 and po.delay_after_send_us == 250
    plain = port_options(115200, RS485())
    assert plain.gpio_chip == ffi.NULL and plain.gpio_line == 0


def test_gpio_options_checked_before_c() -> None:
    with pytest.raises(InvalidValueError, match="gpio_chip"):
        RS485(mode=RS485Mode.GPIO)
    with pytest.raises(InvalidTypeError, match="gpio_chip"):
        RS485(mode=RS485Mode.GPIO, gpio_chip=3)  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError, match="gpio_chip"):
        RS485(mode=RS485Mode.GPIO, gpio_chip="")
    with pytest.raises(InvalidValueError, match="gpio_line"):
        RS485(mode=RS485Mode.GPIO, gpio_chip="/dev/gpiochip0", gpio_line=-1)


def test_gpio_open_fails_on_a_missing_chip(pty: str) -> None:
    with pytest.raises(PortError) as info:
        Port(pty, 115200, RS485(mode=RS485Mode.GPIO, gpio_chip="/nonexistent/gpiochip0"))
    assert "No such file" in str(info.value)
    with pytest.raises(PortError):   # not a GPIO character device
        Port(pty, 115200, RS485(mode=RS485Mode.GPIO, gpio_chip="/dev/null"))
    with Port(pty, 115200, RS485(mode=RS485Mode.NONE)) as port:   # the pty is free again
        assert port.write(b"ok") == 2


def test_cli_rs485_gpio(pty: str, capsys: pytest.CaptureFixture) -> None:
    from fap_py.cli import main

    assert main(["exec", "master", "--port", pty, "--node", "1", "--rs485", "gpio", "01"]) == 2
    assert "--rs485 gpio needs --gpio-chip" in capsys.readouterr().err
    code = main(["exec", "master", "--port", pty, "--node", "1", "--rs485", "gpio",
                 "--gpio-chip", "/nonexistent/gpiochip0", "--gpio-line", "4", "--retries", "0",
                 "--timeout", "0.1", "01"])
    err = capsys.readouterr().err
    assert code != 0 and "No such file" in err
