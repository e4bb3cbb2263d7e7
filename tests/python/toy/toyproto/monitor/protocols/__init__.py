"""The toy's monitor plug-ins, at the path fap_py._protocols looks in: ``<package>.monitor.protocols``."""
