"""The toy protocol's fap sim room (found by name through the protocol table)."""
