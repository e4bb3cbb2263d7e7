"""Each protocol's ``fap <protocol>`` command, one plug-in module per protocol named as in the
protocol table (:mod:`fap_py._protocols`): ``fap_py.commands.protocols.<name>`` defines
``register(subparsers)`` like every module of :mod:`fap_py.commands`. :mod:`fap_py.cli` finds
them by iterating the table (``Protocol.plugin("cli")``), so a new protocol's command is its
plug-in file; the helpers they share stay in ``commands._node`` and ``commands._options``.
"""
