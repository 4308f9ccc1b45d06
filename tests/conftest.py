"""Set the process up first (``envs.platform.setup``: the headless GL back-end and XLA's CPU
flags), before any test module imports mujoco or jax."""
import atexit
import os
import shutil
import tempfile

# The test processes and the commands they start share one compilation cache, fresh for every
# run of the suite: a program is compiled once for all of them, and nothing is left in the
# user's cache. pytest-xdist's workers inherit the directory from the main process.
if "DMO_JAX_COMPILATION_CACHE" not in os.environ:
    os.environ["DMO_JAX_COMPILATION_CACHE"] = tempfile.mkdtemp(prefix="dmo-jax-tests-xla-")
    atexit.register(shutil.rmtree, os.environ["DMO_JAX_COMPILATION_CACHE"], ignore_errors=True)

# The tests run tiny networks on little data, so compiling is most of their time: XLA's CPU
# back-end without its LLVM optimisations compiles the tiny preset's training in half the time.
# The commands themselves keep the full optimisation. The tests' subprocesses inherit the flag.
if "--xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()

from envs.platform import enable_compilation_cache, setup  # noqa: E402

setup()
# The tests' own processes read and write the same cache: most tests build the same tiny networks
# and training steps as other tests, which then load them instead of compiling them again.
enable_compilation_cache()
