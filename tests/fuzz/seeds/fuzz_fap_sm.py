"""Seeds of fuzz_fap_sm: op sequences for the master and the slave."""
import struct

from _vectors import load


def seeds(root):
    fap = load(root, "tests/c/fap/vectors/fap.json")
    # op codes (see fuzz_fap_sm.c): 0x84 frame, 0x85 clock step (us), 2 sent,
    # 3 add, 0x45 remove, 4 queue data
    def fr(msg, dst, src, data=b""):
        return bytes([0x84, msg, dst, src]) + (bytes([len(data) - 1]) + data if msg == 1 else b"")
    master = bytes([1, 10, 10, 10, 10]) + bytes([3, 1, 2]) + fr(4, 0, 1) + \
        bytes([4, 1, 2, 0x41, 0x42, 2, 2]) + fr(2, 0, 1) + bytes([0x85]) + struct.pack("<I", 5000000) + \
        bytes([2]) + fr(1, 0, 1, b"xyz") + bytes([0x45, 1, 2])
    slave = bytes([0, 0, 10, 10, 10, 10]) + fr(3, 1, 0) + bytes([2, 4, 0, 1, 0x55]) + \
        fr(0, 1, 0) + bytes([2, 2, 2]) + fr(1, 1, 0, b"hello") + bytes([2])
    out = [master, slave]
    for v in fap["valid"]:
        data = bytes.fromhex(v["data"])
        body = fr(v["msg"], v["dst"], v["src"], data[:32])
        out.append(bytes([1, 5, 5, 5, 5, 3, v["dst"] % 32, 2]) + body + bytes([2]))
        out.append(bytes([0, max(v["dst"], 1) - 1, 5, 5, 5, 5]) + body + bytes([2, 2]))
    return out
