"""Seeds of fuzz_mikroc: a slave address byte, then mikroC vector frames."""
from _vectors import frames, load


def seeds(root):
    mk = load(root, "tests/vectors/mikroc_rs485.json")
    out = [bytes([v["address"]]) + bytes.fromhex(v["frame"]) for v in mk["valid"]]
    mk_frames = frames(mk)
    return out + [b"\x01" + f for f in mk_frames] + [b"\x32" + b"".join(mk_frames)]
