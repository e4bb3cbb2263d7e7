#!/usr/bin/env python3
"""Write the seed corpora of the fuzz targets from the byte-exact vectors.

    seed_corpus.py OUT_DIR      -> OUT_DIR/<target>/seed-*

Every vector frame (valid and invalid) becomes a seed in its target's input
format (see the comment at the top of each fuzz_*.c)."""
import hashlib
import json
import pathlib
import struct
import sys

ROOT = pathlib.Path(__file__).resolve().parents[2]


def load(path: str) -> dict:
    return json.loads((ROOT / path).read_text())


def frames(vec: dict) -> list:
    out = [bytes.fromhex(v["frame"]) for v in vec.get("valid", []) + vec.get("invalid", [])]
    return out


def write(out: pathlib.Path, target: str, seeds: list) -> int:
    d = out / target
    d.mkdir(parents=True, exist_ok=True)
    for s in seeds:
        (d / ("seed-" + hashlib.sha1(s).hexdigest()[:16])).write_bytes(s)
    return len(seeds)


def fap_sm_seeds(fap: dict) -> list:
    # op codes (see fuzz_fap_sm.c): 0x84 frame, 0x85 clock step (us), 2 sent,
    # 3 add, 0x45 remove, 4 queue data
    def fr(msg, dst, src, data=b""):
        return bytes([0x84, msg, dst, src]) + (bytes([len(data) - 1]) + data if msg == 1 else b"")
    master = bytes([1, 10, 10, 10, 10]) + bytes([3, 1, 2]) + fr(4, 0, 1) + \
        bytes([4, 1, 2, 0x41, 0x42, 2, 2]) + fr(2, 0, 1) + bytes([0x85]) + struct.pack("<I", 5000000) + \
        bytes([2]) + fr(1, 0, 1, b"xyz") + bytes([0x45, 1, 2])
    slave = bytes([0, 0, 10, 10, 10, 10]) + fr(3, 1, 0) + bytes([2, 4, 0, 1, 0x55]) + \
        fr(0, 1, 0) + bytes([2, 2, 2]) + fr(1, 1, 0, b"hello") + bytes([2])
    seeds = [master, slave]
    for v in fap["valid"]:
        data = bytes.fromhex(v["data"])
        body = fr(v["msg"], v["dst"], v["src"], data[:32])
        seeds.append(bytes([1, 5, 5, 5, 5, 3, v["dst"] % 32, 2]) + body + bytes([2]))
        seeds.append(bytes([0, max(v["dst"], 1) - 1, 5, 5, 5, 5]) + body + bytes([2, 2]))
    return seeds


def main() -> int:
    out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "build-fuzz/corpus")
    fap = load("tests/c/fap/vectors/fap.json")
    ex = load("tests/vectors/exec_async.json")
    mk = load("tests/vectors/mikroc_rs485.json")
    g4 = load("tests/vectors/g485.json")
    fap_frames = frames(fap) + [bytes.fromhex(fap["alternate_marker_frame"]["frame"]),
                                bytes.fromhex(fap["stream"]["bytes"])]
    n = write(out, "fuzz_fap_decoder", [bytes([i]) + f for i, f in enumerate(fap_frames)] +
              [b"\x07" + b"".join(fap_frames)])
    n += write(out, "fuzz_fap_sm", fap_sm_seeds(fap))
    ex_frames = frames(ex)
    n += write(out, "fuzz_exec_bytein", [b"\x00" + f for f in ex_frames] +
               [b"\x03" + b"".join(ex_frames), b"\x00" + b"".join(ex_frames)])
    # descriptor: n, then (offset u16, size code, count) per item, terminator flag, data
    reading = bytes([4]) + struct.pack("<HBB", 0, 0, 1) + struct.pack("<HBB", 2, 1, 1) + \
        struct.pack("<HBB", 4, 2, 1) + struct.pack("<HBB", 8, 1, 3) + b"\x01" + bytes(range(16))
    unordered = bytes([3]) + struct.pack("<HBB", 8, 3, 2) + struct.pack("<HBB", 0, 2, 1) + \
        struct.pack("<HBB", 4, 0x85, 1) + b"\x00" + bytes(range(32))
    n += write(out, "fuzz_exec_pack", [reading, unordered])
    mk_frames = frames(mk)
    seeds = []
    for v in mk["valid"]:
        seeds.append(bytes([v["address"]]) + bytes.fromhex(v["frame"]))
    seeds += [b"\x01" + f for f in mk_frames] + [b"\x32" + b"".join(mk_frames)]
    n += write(out, "fuzz_mikroc", seeds)
    g_frames = [bytes.fromhex(v["frame"]) for v in g4["valid"]]
    n += write(out, "g485", g_frames + [b"".join(g_frames)])
    print(f"seed_corpus: {n} seeds in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
