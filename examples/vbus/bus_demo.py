#!/usr/bin/env python3
"""A 3-node virtual RS-485 bus at 9600 baud: a request, an answer, a
collision, then the capture file read back.

    python3 examples/vbus/bus_demo.py [CAPTURE_FILE]

Nodes are plain pyserial ports, as a real program would use; the bus is
fap_py.vbus.VirtualBus (the C relay of libfap).
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import serial

from fap_py.vbus import VirtualBus, read_capture


def main() -> int:
    capture = Path(sys.argv[1]) if len(sys.argv) > 1 else \
        Path(tempfile.mkdtemp(prefix="bus-demo-")) / "bus.cap"
    with VirtualBus(ports=3, baud=9600, capture=capture, seed=1) as bus:
        print("ports:", *bus.paths)
        master, slave, sniffer = (serial.Serial(p, 9600, timeout=2) for p in bus.paths)
        t0 = time.monotonic()
        master.write(bytes(range(100)))
        answer_seen = sniffer.read(100)
        slave.read(100)
        print(f"100-byte request: {(time.monotonic() - t0) * 1e3:.1f} ms on the wire "
              f"(ideal 104.2), sniffer got {len(answer_seen)} bytes")
        slave.write(b"\x01\x02\x03\x04")   # answer
        print("master got answer:", master.read(4).hex(" "))
        sniffer.read(4)
        master.write(b"\x11" * 10)          # both talk at once
        slave.write(b"\x22" * 10)
        print("sniffer during collision:", sniffer.read(20).hex(" "))
        print("stats:", bus.stats)
        for s in (master, slave, sniffer):
            s.close()
    cap = read_capture(capture)
    print(f"capture {capture}: {len(cap.records)} lines, "
          f"{len(cap.events_of('collision'))} collision(s)")
    for rec in cap.records[:6]:
        print(f"  t={rec.t_us / 1000:9.3f} ms port {rec.port}: {rec.data.hex(' ')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
