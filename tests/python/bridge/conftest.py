"""Fixtures of the bridge tests: a real mosquitto, an MQTT observer, bridge configs.

mosquitto and paho-mqtt may be missing only outside CI: with ``CI`` set, a
missing tool fails the test instead of skipping it.
"""
from __future__ import annotations

import os
import sys
from typing import Any, Callable, Iterator, List

import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bridge_helpers import Observer, need
from mosquitto import MOSQUITTO, Mosquitto


@pytest.fixture(scope="session")
def paho_mqtt() -> Any:
    try:
        import paho.mqtt.client as mqtt
    except ImportError:
        mqtt = None
    need("paho-mqtt (pip install 'fap_py[bridge]')", mqtt is not None)
    return mqtt


@pytest.fixture
def broker(tmp_path: Any, paho_mqtt: Any) -> Iterator[Mosquitto]:
    need("mosquitto", MOSQUITTO is not None)
    with Mosquitto(str(tmp_path / "broker")) as b:
        yield b


@pytest.fixture
def observer_factory(paho_mqtt: Any) -> Iterator[Callable[..., Observer]]:
    made: List[Observer] = []

    def make(port: int, topics: str = "fap/#", **kw: Any) -> Observer:
        o = Observer(paho_mqtt, port, topics, **kw)
        made.append(o)
        return o

    yield make
    for o in made:
        o.close()
