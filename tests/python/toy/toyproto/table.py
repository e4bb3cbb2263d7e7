"""The toy's row of the protocol table: the one edit a fifth protocol makes to
fap_py/_protocols.py, kept here because the toy lives out of tree
(``FAP_EXTRA_PROTOCOLS=toyproto.table:TOY`` loads it in a child process)."""

from fap_py._protocols import Protocol

TOY = Protocol("toy", "toy protocol (tests only)", 250, "toyproto.binding", package="toyproto")
