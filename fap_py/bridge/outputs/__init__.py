"""The bridge's outputs, found by name (docs/bridge.md, "Outputs").

Each built-in output is one module of this package, named after it, with a
``create(config) -> Output | None`` (None: not configured)::

    fap_py.bridge.outputs.metrics         [metrics] listen: the Prometheus endpoint
    fap_py.bridge.outputs.homeassistant   buses with homeassistant = true: MQTT discovery
    fap_py.bridge.outputs.sparkplug       [sparkplug]: the bridge as a Sparkplug B edge node

More outputs plug in with no edit here: :func:`register` a factory, or name
it in ``FAP_BRIDGE_OUTPUTS`` (``module:ATTR``, comma-separated, as
``FAP_EXTRA_PROTOCOLS`` names protocols), which a child process inherits.
"""
from __future__ import annotations

import importlib
import os
from typing import Callable, Dict, List, Optional, Tuple

from ...errors import InvalidTypeError, InvalidValueError
from ..config import BridgeConfig
from ._base import EVENT_KINDS, RX, SEEN, STATE, BridgeView, NodeEvent, NodeView, Output, OutputBase

#: the built-in outputs, in the order they start (the metrics endpoint first: a port
#: already taken stops the bridge before anything connects)
BUILTIN: Tuple[str, ...] = ("metrics", "homeassistant", "sparkplug")

#: out-of-tree outputs: ``module:ATTR`` references to factories, comma-separated
ENV_EXTRA = "FAP_BRIDGE_OUTPUTS"

Factory = Callable[[BridgeConfig], Optional[Output]]


class UnknownOutputError(InvalidValueError):
    """An output name that is not built in nor registered, or a reference that does not load."""


_extra: Dict[str, Factory] = {}


def register(name: str, factory: Factory) -> None:
    """Add an output: ``factory(config)`` returns it, or None when ``config`` does not ask for it."""
    if not isinstance(name, str) or not name or not callable(factory):
        raise InvalidTypeError("register(name: str, factory: callable)")
    if name in BUILTIN or name in _extra:
        raise InvalidValueError(f"output {name!r:.40} is already registered")
    _extra[name] = factory


def unregister(name: str) -> None:
    if not isinstance(name, str):
        raise InvalidTypeError(f"name must be a str, not {type(name).__name__}")
    _extra.pop(name, None)


def _env() -> Dict[str, Factory]:
    out: Dict[str, Factory] = {}
    for ref in filter(None, (r.strip() for r in os.environ.get(ENV_EXTRA, "").split(","))):
        mod, _, attr = ref.partition(":")
        try:
            factory = getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError, ValueError) as e:
            raise UnknownOutputError(f"{ENV_EXTRA}: cannot load {ref!r:.100}: {e}") from None
        if not callable(factory):
            raise UnknownOutputError(f"{ENV_EXTRA}: {ref!r:.100} is not callable")
        out[str(getattr(factory, "name", None) or attr)] = factory
    return out


def names() -> Tuple[str, ...]:
    """Every output's name: the built-in ones, then the registered ones."""
    return BUILTIN + tuple(n for n in {**_extra, **_env()} if n not in BUILTIN)


def factory(name: str) -> Factory:
    """The factory of the output called ``name``."""
    if not isinstance(name, str):
        raise InvalidTypeError(f"name must be a str, not {type(name).__name__}")
    if name in BUILTIN:
        return importlib.import_module(f"{__name__}.{name}").create
    extra = {**_extra, **_env()}
    if name not in extra:
        raise UnknownOutputError(f"no bridge output {name!r:.40} (known: {', '.join(names())})")
    return extra[name]


def build(config: BridgeConfig) -> List[Output]:
    """The outputs ``config`` asks for, in :func:`names` order."""
    if not isinstance(config, BridgeConfig):
        raise InvalidTypeError(f"config must be a BridgeConfig, not {type(config).__name__}")
    out: List[Output] = []
    for name in names():
        o = factory(name)(config)
        if o is None:
            continue
        for hook in ("subscriptions", "start", "on_connect", "on_node_event", "on_message", "on_tick", "stop"):
            if not callable(getattr(o, hook, None)):
                raise InvalidTypeError(f"output {name!r:.40} has no {hook}() (see fap_py.bridge.outputs.base.Output)")
        out.append(o)
    return out


__all__ = ["BUILTIN", "BridgeView", "ENV_EXTRA", "EVENT_KINDS", "NodeEvent", "NodeView", "Output", "OutputBase",
           "RX", "SEEN", "STATE", "UnknownOutputError", "build", "factory", "names", "register", "unregister"]

