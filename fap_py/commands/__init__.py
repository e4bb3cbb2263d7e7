"""Subcommands of the ``fap`` console command.

Each module here defines ``register(subparsers)`` that adds one subcommand
whose ``func(args) -> int`` runs it; :mod:`fap_py.cli` discovers them.
"""
