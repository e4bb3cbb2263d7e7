"""Seeds of the G485 parser fuzzer (g485_fuzz.py): the valid vector frames."""
from _vectors import load


def seeds(root):
    g = [bytes.fromhex(v["frame"]) for v in load(root, "tests/vectors/g485.json")["valid"]]
    return g + [b"".join(g)]
