"""Who may talk to ``fap web``: loopback names, without aiohttp (the library checks its
arguments before the optional dependency is imported)."""
from __future__ import annotations

import ipaddress


def host_name(host: str) -> str:
    """The name of a Host header: ``[::1]:80`` -> ``::1``, ``localhost:80`` -> ``localhost``."""
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return host == "localhost"


__all__ = ["host_name", "is_loopback"]
