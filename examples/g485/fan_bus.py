#!/usr/bin/env python3
"""Three simulated G485 fans on a virtual RS-485 bus, driven by the master.

Shows a scan, a checked read, a write, a refused write, saving to EEPROM, the error word, an ID
change and a synchronised (non-real-time) write applied by one broadcast.

    python examples/g485/fan_bus.py        (add -v to see every frame)
"""
from __future__ import annotations

import logging
import sys
import tempfile

from fap_py.g485 import ErrorBit, G485Master, SetCommand, SimDevice, Simulator, WriteRefusedError
from fap_py.vbus import VirtualBus

SPEED = 8  # a private register: fan speed in percent


def show(device: SimDevice, first: int, last: int) -> None:
    if first <= SPEED <= last:
        print(f"    fan {device.address} now runs at {device.applied[SPEED]} %")


def main() -> int:
    if "-v" in sys.argv:
        logging.basicConfig(level=logging.DEBUG, format="%(name)s %(message)s")
    with tempfile.TemporaryDirectory(prefix="g485-") as eeprom_dir:
        return run(eeprom_dir)


def run(eeprom_dir: str) -> int:
    fans = [SimDevice(n, identity=(11, 3, 1, 1, 2), eeprom_path=f"{eeprom_dir}/fan{n}.json", on_apply=show)
            for n in (1, 2, 3)]
    with VirtualBus(ports=2) as bus, Simulator(bus.paths[1], fans), G485Master(bus.paths[0]) as master:
        print("fans on the bus:", master.scan(range(1, 9), timeout=0.05))
        print("identity of fan 1 (registers 1..7):", list(master.read(1, 1, 7)))
        print("fan 2 to 40 %:")
        master.write(2, SPEED, 40)
        master.set(2, SetCommand.SAVE_EEPROM)
        try:
            master.write(3, 1, 0)  # register 1 is read-only: the device refuses, its check byte stays
        except WriteRefusedError as exc:
            print("refused:", exc)
        word = master.error_word(3)
        print(f"fan 3 error word after writing a read-only register: 0x{word:04x}",
              "(READ_ONLY)" if word & ErrorBit.READ_ONLY else "")
        master.set(3, SetCommand.CLEAR_ERROR_WORD)
        print("fan 3 becomes fan 30")
        master.change_id(3, 30, save=True)
        print("all fans change speed at the same moment (0x78, writes, broadcast 0x77):")
        master.sync_write([(1, SPEED, 70), (2, SPEED, 70), (30, SPEED, 70)], back_to_real_time=True)
        print("master statistics:", master.stats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
