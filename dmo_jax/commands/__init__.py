"""The method's commands, one module per ``bin/`` command (``train_all``, ``evaluate``, ``compare``,
``reproduce``, ``cost``, ``benchmark``, ``ebm_misses``), each with ``main(argv=None)``; ``common``
holds the options they share. The simulator's commands are ``envs.commands``.
"""
