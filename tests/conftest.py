"""Set the process up first (``envs.platform.setup``: the headless GL back-end and XLA's CPU
flags), before any test module imports mujoco or jax."""
import atexit
import os
import shutil
import tempfile

# The commands the tests start (each a new process) share one compilation cache, fresh for
# every run of the suite: a program is compiled once for all of them, and nothing is left in
# the user's cache.
_CACHE = tempfile.mkdtemp(prefix="dmo-jax-tests-xla-")
atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)
os.environ.setdefault("DMO_JAX_COMPILATION_CACHE", _CACHE)

from envs.platform import setup  # noqa: E402

setup()
