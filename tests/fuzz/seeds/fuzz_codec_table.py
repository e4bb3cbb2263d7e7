"""Seeds of fuzz_codec_table: for every row that names its vectors
(tests/c/codec/rows/<name>.row, the codec test's own files), "<name>\\0",
a chunk seed byte, then the row's vector frames: one seed per frame and one
of them all. A new row's seeds come with its .row file."""
from _vectors import frames, load


def seeds(root):
    out = []
    for row in sorted((root / "tests" / "c" / "codec" / "rows").glob("*.row")):
        keys = dict(line.split(None, 1) for line in row.read_text().splitlines()
                    if line.strip() and not line.startswith("#"))
        fs = frames(load(root, keys["vectors"].strip()))
        head = row.stem.encode() + b"\0"
        out += [head + bytes([i % 256]) + f for i, f in enumerate(fs)] + [head + b"\x05" + b"".join(fs)]
    return out
