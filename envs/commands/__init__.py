"""The simulator's commands, one module per ``bin/`` command (``render``, ``execute``,
``generate_data``, ``task_report``), each with ``main(argv=None)``; ``common`` holds what every
command shares: one-line failures, option checks, task names, output files.
"""
