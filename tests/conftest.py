"""Import the simulator package first: it selects the GL back-end and XLA's CPU flags,
which must happen before MuJoCo renders or JAX initialises."""
import os

# Tests compile afresh: the commands they call would otherwise fill the user's XLA cache.
os.environ.setdefault("DMO_JAX_COMPILATION_CACHE", "off")

import envs  # noqa: F401,E402
