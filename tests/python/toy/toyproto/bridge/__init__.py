"""The toy protocol's bridge plug-in lives in ``protocols/toy.py`` (as fap_py.bridge.protocols.<name>)."""
