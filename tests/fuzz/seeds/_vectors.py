"""Shared by the seed modules (tests/fuzz/seeds/<target>.py): the vector files."""
import json
import pathlib


def load(root: pathlib.Path, path: str) -> dict:
    return json.loads((root / path).read_text())


def frames(vec: dict) -> list:
    """Every vector frame, valid and invalid."""
    return [bytes.fromhex(v["frame"]) for v in vec.get("valid", []) + vec.get("invalid", [])]
