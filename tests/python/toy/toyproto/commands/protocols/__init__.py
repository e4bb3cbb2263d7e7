"""The toy's `fap toy` command plug-in, where fap_py keeps the built-in ones."""
