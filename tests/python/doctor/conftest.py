"""Fixtures of the `fap doctor` tests."""
from __future__ import annotations

import pytest
from doctor_helpers import Tree


@pytest.fixture
def tree(tmp_path) -> Tree:
    return Tree(tmp_path / "root")


@pytest.fixture
def fap_main(capsys, monkeypatch):
    """fap_main(*args) -> (code, stdout, stderr) through fap_py.cli.main."""
    from fap_py.cli import main

    monkeypatch.setenv("COLUMNS", "100")

    def run(*args: str):
        capsys.readouterr()
        code = main(list(args))
        cap = capsys.readouterr()
        return code, cap.out, cap.err
    return run
