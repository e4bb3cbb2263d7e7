"""Seeds of fuzz_exec_pack: pack descriptors with data."""
import struct


def seeds(root):
    # descriptor: n, then (offset u16, size code, count) per item, terminator flag, data
    reading = bytes([4]) + struct.pack("<HBB", 0, 0, 1) + struct.pack("<HBB", 2, 1, 1) + \
        struct.pack("<HBB", 4, 2, 1) + struct.pack("<HBB", 8, 1, 3) + b"\x01" + bytes(range(16))
    unordered = bytes([3]) + struct.pack("<HBB", 8, 3, 2) + struct.pack("<HBB", 0, 2, 1) + \
        struct.pack("<HBB", 4, 0x85, 1) + b"\x00" + bytes(range(32))
    return [reading, unordered]
