"""Seeds of fuzz_exec_bytein: a buffer-size byte, then exec async vector frames."""
from _vectors import frames, load


def seeds(root):
    ex = frames(load(root, "tests/vectors/exec_async.json"))
    return [b"\x00" + f for f in ex] + [b"\x03" + b"".join(ex), b"\x00" + b"".join(ex)]
