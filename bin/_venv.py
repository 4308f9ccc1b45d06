"""Run ``bin/`` commands in the project's virtual environment.

``bin/evaluate ...`` starts with whatever ``python3`` is on the PATH; when that is not the
environment ``bin/setup`` made (``$DMO_VENV`` or ``.venv``) and that environment exists, the
command re-executes itself there, so every command works as the README writes it.
"""
import os
import sys


def use_project_venv() -> None:
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    venv = os.environ.get("DMO_VENV") or os.path.join(root, ".venv")
    python = os.path.join(venv, "bin", "python")
    if os.path.realpath(sys.prefix) != os.path.realpath(venv) and os.access(python, os.X_OK):
        os.execv(python, [python, *sys.argv])
