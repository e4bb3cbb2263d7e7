"""The project's address, one constant: pyproject.toml's ``[project.urls]``
hold the same value (a test checks it), the Wireshark extcap help and the
MQTT discovery payload's ``support_url`` are built from it."""
from __future__ import annotations

PROJECT_URL = "https://github.com/libfap/fap_py"


def docs_url(page: str) -> str:
    """The address of ``docs/<page>`` on the project's main branch."""
    return f"{PROJECT_URL}/blob/main/docs/{page}"


__all__ = ["PROJECT_URL", "docs_url"]
