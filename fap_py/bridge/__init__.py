"""``fap bridge``: RS-485 buses to an MQTT broker (docs/bridge.md).

Importing this package does not import paho-mqtt; :class:`Bridge` does,
when it is built (``pip install 'fap_py[bridge]'``).

>>> from fap_py.bridge import Bridge, load_config
>>> with Bridge(load_config("bridge.toml")) as bridge:    # doctest: +SKIP
...     bridge.wait_connected(10)
"""

from .bridge import Bridge
from .buses import TxError
from .config import (
    BridgeConfig,
    BridgeConfigError,
    BridgeConfigTypeError,
    BrokerConfig,
    BusConfig,
    SparkplugConfig,
)
from .config import load as load_config
from .files import BridgeFileError
from .mqtt import INSTALL_HINT, BrokerRefusedError, MissingDependencyError
from .store import StoreError

__all__ = ["Bridge", "BridgeConfig", "BridgeConfigError", "BridgeConfigTypeError", "BridgeFileError",
           "BrokerConfig", "BrokerRefusedError", "BusConfig", "INSTALL_HINT",
           "MissingDependencyError", "SparkplugConfig", "StoreError", "TxError", "load_config"]
