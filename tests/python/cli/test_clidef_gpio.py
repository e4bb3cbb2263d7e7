"""Issue 33, from hostile input: `--gpio-chip` without `--rs485 gpio` is a
usage error (it was silently ignored); a GPIO error names the chip, not the
serial port; `--gpio-line 512` (beyond the C bound) is a usage error naming
the option, not a bare `open: Invalid argument`. (This host has no
gpiochip: a chip's own line count is checked by the same code on a real
one, GPIO_GET_CHIPINFO.)"""
from __future__ import annotations

from pathlib import Path

import pytest

COMMANDS = [
    ("exec", "master", "--node", "5", "--timeout", "0.05", "--retries", "0", "01"),
    ("mikroc", "master", "--address", "5", "--timeout", "0.05", "--retries", "0", "01"),
    ("g485", "read", "--address", "1", "--register", "1", "--timeout", "0.05",
     "--retries", "0"),
]


@pytest.mark.parametrize("cmd", COMMANDS, ids=lambda c: " ".join(c[:2]))
def test_gpio_options_are_checked(cmd: tuple, fap, bus, tmp_path: Path) -> None:
    port = bus.paths[0]
    args = [*cmd[:2], "--port", port, *cmd[2:]]

    for mode in (None, "none", "auto"):
        extra = [] if mode is None else ["--rs485", mode]
        r = fap(*args, *extra, "--gpio-chip", "/dev/gpiochip0")
        assert r.code == 2, r
        assert r.err == (f"fap: error: --gpio-chip is for --rs485 gpio (the mode is "
                         f"{mode or 'auto'}): add --rs485 "
                         "gpio, or drop --gpio-chip\n")

    r = fap(*args, "--rs485", "gpio", "--gpio-chip", "/dev/gpiochip0", "--gpio-line", "512")
    assert (r.code, r.err) == (2, "fap: error: --gpio-line 512: a GPIO line offset is 0..511\n")

    missing = tmp_path / "gpiochip9"
    r = fap(*args, "--rs485", "gpio", "--gpio-chip", str(missing), "--gpio-line", "1")
    assert r.code == 3, r
    assert r.err == (f"fap: error: {missing}: --gpio-chip: cannot open the GPIO chip "
                     "(No such file or directory)\n")
    assert port not in r.err

    for not_a_chip in ("/dev/null", str(tmp_path)):
        if not_a_chip == str(tmp_path):
            not_a_chip = str(tmp_path / "regular")
            Path(not_a_chip).write_text("")
        r = fap(*args, "--rs485", "gpio", "--gpio-chip", not_a_chip)
        assert r.code == 3, r
        assert r.err.startswith(f"fap: error: {not_a_chip}: --gpio-chip: not a GPIO character "
                                "device (GPIO_GET_CHIPINFO refused: "), r
        assert port not in r.err
