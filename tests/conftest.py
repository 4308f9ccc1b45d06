"""Set the process up first (``envs.platform.setup``: the headless GL back-end and XLA's CPU
flags), before any test module imports mujoco or jax; and the networks several test modules share
(``trained``)."""
import os
import shutil
from pathlib import Path

from envs.platform import (add_xla_flag, collect_garbage_rarely, enable_compilation_cache, setup,
                           user_cache_dir)

#: The tests' compilation cache is emptied at the start of a run once it holds more than this.
TEST_CACHE_LIMIT_BYTES = 512 * 2**20

# The test processes and the commands they start share one compilation cache, kept between runs
# of the suite in a directory of its own: the tests compile with other XLA flags than the
# commands, so their programs could never serve a command. A program is compiled once for all of
# a run's processes, and a later run of unchanged code reads it back: 433 instead of 657 s
# (BENCHMARKS.md, "Test suite"). Edits leave programs no later run reads (a run's take about
# 41 MB), so the directory starts afresh past TEST_CACHE_LIMIT_BYTES. pytest-xdist's workers
# inherit it from the main process; DMO_JAX_COMPILATION_CACHE chooses another one (``off``: none).
if "DMO_JAX_COMPILATION_CACHE" not in os.environ:
    cache = Path(user_cache_dir("xla-tests"))
    if cache.is_dir() and sum(f.stat().st_size for f in cache.iterdir() if f.is_file()) > TEST_CACHE_LIMIT_BYTES:
        shutil.rmtree(cache, ignore_errors=True)
    os.environ["DMO_JAX_COMPILATION_CACHE"] = str(cache)

import pytest  # noqa: E402

# The tests run tiny networks on little data, so compiling is most of their time: XLA's CPU
# back-end without its LLVM optimisations compiles the tiny preset's training in half the time.
# The commands themselves keep the full optimisation. The tests' subprocesses inherit the flag.
add_xla_flag("--xla_backend_optimization_level=0")
setup()
# The tests' own processes read and write the same cache: most tests build the same tiny networks
# and training steps as other tests, which then load them instead of compiling them again. The
# thousands of small programs they run op by op cost about as much to write as to compile, so
# they are not kept (about 30-70 s less CPU for the suite; BENCHMARKS.md, "Test suite"); a command
# a test runs in-process sets the commands' own threshold, 0, from then on in that process.
enable_compilation_cache(min_compile_seconds=0.1)
collect_garbage_rarely()  # again, now that jax is imported

from helpers import built_once  # noqa: E402


@pytest.fixture(scope="session")
def trained(tmp_path_factory, worker_id):
    """``(data, runs, summary)``: tiny datasets of reach_target (20 train, 4 test episodes) and a
    tiny VAE + EBM + DMO of the paper's recipe trained on them, with the training summary; built
    once for all of the suite's workers. Tests must not write into them (copy them first)."""
    from dmo_jax import workflow
    from dmo_jax.config import get_preset
    from envs import dataset
    from envs.tasks import get_task

    def build(root):
        data, work = root / "data", root / "runs"
        tiny = get_preset("tiny")
        task = get_task("reach_target", tiny.image_size)
        dataset.generate_split(task, "train", 20, data, batch=20, verbose=False)
        dataset.generate_split(task, "test", 4, data, batch=4, verbose=False)
        return workflow.train_task("reach_target", tiny, data, work, log=lambda m: None)

    root, summary = built_once(tmp_path_factory, worker_id, "trained-reach_target", build)
    return root / "data", root / "runs", summary


@pytest.fixture(scope="session")
def trained_bank(trained, tmp_path_factory, worker_id):
    """``(data, runs, summary)``: ``trained``'s data and networks, plus the bank recipe's EBM, DMO
    and selection head trained beside them (sharing the VAE). Tests must not write into them."""
    from dmo_jax import workflow
    from dmo_jax.config import get_preset

    def build(root):
        data, work = shutil.copytree(trained[0], root / "data"), shutil.copytree(trained[1], root / "runs")
        return workflow.train_task("reach_target", get_preset("tiny", recipe="bank"), data, work, log=lambda m: None)

    root, summary = built_once(tmp_path_factory, worker_id, "trained-bank-reach_target", build)
    return root / "data", root / "runs", summary
