"""The toy's soak plug-in (toyproto.soak.toy), where fap_py keeps the built-in ones."""
