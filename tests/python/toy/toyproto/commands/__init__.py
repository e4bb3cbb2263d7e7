"""The toy's commands (toyproto.commands.protocols.toy), laid out as fap_py.commands."""
