"""The toy protocol's sim plug-in: one file, as a fifth protocol's simulator is."""
