"""Import the simulator package first: it selects the GL back-end and XLA's CPU flags,
which must happen before MuJoCo renders or JAX initialises."""
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

import envs  # noqa: F401,E402
