"""Shared test helpers: random parameters and motions without compiling ``init``; a directory
built once per run of the suite and shared by its worker processes."""
import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from envs.motion import NUM_STEPS, POSE_DIM, time_grid


def random_params(net, seed=0):
    """Random parameters of the right shapes, drawn with numpy.

    XLA:CPU takes 10-25 s to compile a network's ``init`` (one threefry + truncated normal
    per array), longer than everything else here; the initialiser's structure is covered by
    ``param_shapes`` (``jax.eval_shape`` of ``init``). Kernels get fan-in-scaled normals,
    vectors (biases, norm scales, layer scales) O(0.1-1) values, so every layer matters.
    """
    rng = np.random.default_rng(seed)

    def draw(x):
        if len(x.shape) >= 2:
            return rng.normal(0.0, 1.0 / np.sqrt(np.prod(x.shape[:-1])), x.shape).astype(np.float32)
        return rng.uniform(0.1, 1.0, x.shape).astype(np.float32)

    return jax.tree.map(lambda x: jnp.asarray(draw(x)), net.param_shapes())


def random_motions(key, n):
    """Plausible motions: uv in the image (some outside), grasp in [0, 1], time grid."""
    k1, k2, k3 = jax.random.split(key, 3)
    m = jax.random.uniform(k1, (n, NUM_STEPS, POSE_DIM), minval=-1.1, maxval=1.1)
    m = m.at[..., 9].set(jax.random.uniform(k2, (n, NUM_STEPS)))
    m = m.at[..., 2].set(jax.random.uniform(k3, (n, NUM_STEPS), minval=0.3, maxval=1.5))
    return m.at[..., 10].set(jnp.asarray(time_grid()))


def built_once(tmp_path_factory, worker_id: str, name: str, build: Callable[[Path], dict]) -> tuple[Path, dict]:
    """``(root, info)``: ``build(root)`` run once per run of the suite, whichever worker process
    asks first; the others wait for it, then share ``root`` and the JSON ``info`` it returned.
    Users must not write into ``root`` (copy it first)."""
    base = tmp_path_factory.getbasetemp()
    shared = base if worker_id == "master" else base.parent  # pytest-xdist: the workers' common parent
    root, done = shared / name, shared / f"{name}.json"
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, even if build raises
        if not done.is_file():
            root.mkdir(exist_ok=True)
            done.write_text(json.dumps(build(root)))
    return root, json.loads(done.read_text())


def run_on_two_devices(script: str) -> dict:
    """Run the Python ``script`` in a subprocess whose host platform has two devices (with the
    suite's XLA flags, conftest.py; ``sys.argv[1]`` is the repository root) and return the JSON
    object its last line of stdout prints."""
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2"}
    proc = subprocess.run([sys.executable, "-c", script, str(Path(__file__).resolve().parents[1])], env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])
