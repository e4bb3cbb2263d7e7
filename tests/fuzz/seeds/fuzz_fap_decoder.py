"""Seeds of fuzz_fap_decoder: a chunk seed byte, then FAP vector frames."""
from _vectors import frames, load


def seeds(root):
    fap = load(root, "tests/c/fap/vectors/fap.json")
    fap_frames = frames(fap) + [bytes.fromhex(fap["alternate_marker_frame"]["frame"]),
                                bytes.fromhex(fap["stream"]["bytes"])]
    return [bytes([i % 256]) + f for i, f in enumerate(fap_frames)] + [b"\x07" + b"".join(fap_frames)]
