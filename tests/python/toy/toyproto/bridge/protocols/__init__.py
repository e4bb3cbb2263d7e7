"""Bridge plug-ins of the toy package (found by name through the protocol table)."""
