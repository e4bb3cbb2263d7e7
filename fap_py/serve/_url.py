"""``fapd://`` URLs: where a daemon listens and how a client joins it. Private.

* ``fapd:///run/fap/bus0.sock`` - a Unix socket (the path after ``fapd://``);
* ``fapd://host:port`` - TCP (``[::1]:port`` for IPv6);
* query: ``weight=N`` (1..), ``priority=N`` (0..), ``token=TEXT``, ``name=TEXT``,
  ``timeout=S`` (the longest wait for the daemon's answer, seconds).

The listener forms of ``fap serve --listen`` are ``unix:PATH`` and ``tcp://HOST:PORT``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Dict, Optional, Tuple
from urllib.parse import parse_qsl, unquote

from ._errors import BadUrlError

SCHEME = "fapd://"
#: the query keys a client URL may carry
QUERY_KEYS = ("weight", "priority", "token", "name", "timeout")


def is_daemon_url(port: Any) -> bool:
    """Whether ``port`` (a str, bytes or path) names a daemon (``fapd://...``)."""
    if isinstance(port, os.PathLike):
        try:
            port = os.fspath(port)
        except TypeError:
            return False
    if isinstance(port, bytes):
        return port[:7].lower() == SCHEME.encode()
    return isinstance(port, str) and port[:7].lower() == SCHEME


@dataclass(frozen=True)
class Address:
    """A socket address: ``kind`` "unix" (``path``) or "tcp" (``host``, ``port``)."""

    kind: str
    path: str = ""
    host: str = ""
    port: int = 0

    def __str__(self) -> str:
        if self.kind == "unix":
            return f"unix:{self.path}"
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"tcp://{host}:{self.port}"

    def url(self) -> str:
        """The client URL of this address."""
        if self.kind == "unix":
            return SCHEME + self.path
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{SCHEME}{host}:{self.port}"


@dataclass(frozen=True)
class ClientUrl:
    """A parsed client URL."""

    address: Address
    query: Dict[str, str] = field(default_factory=dict)
    text: str = ""


def _host_port(text: str, what: str, zero_ok: bool = False) -> Tuple[str, int]:
    if text.startswith("["):
        host, sep, rest = text[1:].partition("]")
        if not sep or not rest.startswith(":"):
            raise BadUrlError(f"{what}: an IPv6 host is [addr]:port", what)
        port_text = rest[1:]
    else:
        host, sep, port_text = text.rpartition(":")
        if not sep:
            raise BadUrlError(f"{what}: no :port (fapd://host:port, or fapd:///path for a Unix socket)", what)
    if not host:
        raise BadUrlError(f"{what}: no host", what)
    if not port_text.isdigit() or not (0 if zero_ok else 1) <= int(port_text) < 65536:
        raise BadUrlError(f"{what}: port must be {0 if zero_ok else 1}..65535, not {port_text!r}", what)
    return host, int(port_text)


def parse_client_url(url: Any) -> ClientUrl:
    """``fapd:///path?weight=2`` or ``fapd://host:port?token=...`` as a :class:`ClientUrl`.
    Raises :class:`~fap_py.serve.BadUrlError` (a port error and a bad value)."""
    if isinstance(url, os.PathLike):
        url = os.fspath(url)
    if isinstance(url, bytes):
        url = os.fsdecode(url)
    if not isinstance(url, str):
        raise BadUrlError(f"a daemon URL is a str, not {type(url).__name__}")
    if not is_daemon_url(url) or "\0" in url:
        raise BadUrlError(f"{url[:80]!r} is not a fapd:// URL", url[:80])
    rest = url[len(SCHEME):]
    rest, _, qs = rest.partition("?")
    query: Dict[str, str] = {}
    for key, value in parse_qsl(qs, keep_blank_values=True):
        if key not in QUERY_KEYS:
            raise BadUrlError(f"{url}: unknown query key {key!r} (known: {', '.join(QUERY_KEYS)})", url)
        query[key] = value
    if rest.startswith("/"):
        path = unquote(rest)
        if len(os.fsencode(path)) > 107:
            raise BadUrlError(f"{url}: a Unix socket path is at most 107 bytes", url)
        return ClientUrl(Address("unix", path=path), query, url)
    host, port = _host_port(rest.rstrip("/"), url)
    return ClientUrl(Address("tcp", host=host, port=port), query, url)


def parse_listen(text: Any) -> Address:
    """A ``--listen`` value: ``unix:PATH`` or ``tcp://HOST:PORT`` (a client URL too)."""
    if not isinstance(text, str):
        raise BadUrlError(f"a listen address is a str, not {type(text).__name__}")
    if text.startswith("unix:"):
        path = text[5:]
        if not path or "\0" in path or len(os.fsencode(path)) > 107:
            raise BadUrlError(f"--listen {text!r}: unix:PATH, a path of 1..107 bytes", text)
        return Address("unix", path=path)
    if text.startswith("tcp://"):
        host, port = _host_port(text[6:].rstrip("/"), text, zero_ok=True)   # 0: any free port
        return Address("tcp", host=host, port=port)
    if is_daemon_url(text):
        return parse_client_url(text).address
    raise BadUrlError(f"--listen {text!r}: unix:PATH or tcp://HOST:PORT", text)


def is_loopback(host: str) -> bool:
    """A host that only this machine reaches."""
    import ipaddress

    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def query_int(q: Dict[str, str], key: str, default: Optional[int], url: str) -> Optional[int]:
    text = q.get(key)
    if text is None:
        return default
    if not text.isdigit():
        raise BadUrlError(f"{url}: {key} must be a whole number, not {text!r}", url)
    return int(text)
