"""Seconds per training step of each model (``bin/benchmark --only train-step``)."""
from __future__ import annotations

import os
import statistics
import time

import jax
import numpy as np

from dmo_jax.config import get_preset


def training_step_benchmark(preset, repeats: int = 5) -> dict:
    """Seconds per optimiser step of the VAE, EBM and DMO: the real jitted ``train_step`` of
    :mod:`dmo_jax.training` (losses, negative sampling, augmentation, Adam) at the preset's
    sizes and batches, on synthetic data. ``preset`` is a name or a
    :class:`~dmo_jax.config.Preset`. Returns per model the median step time, the compile
    time and the time for the preset's step count.
    """
    from envs.motion import time_grid

    from dmo_jax import training
    from dmo_jax.data import MotionDataset

    p = get_preset(preset) if isinstance(preset, str) else preset
    s = p.image_size
    rng = np.random.default_rng(0)
    # enough motions for every batch and for the recipe's near negatives (random "neighbours": the
    # cost does not depend on which motions they are)
    n = max(p.train.vae_batch, p.train.ebm_batch, p.train.dmo_batch, p.train.near_pool + 1)
    motions = np.concatenate(
        [rng.uniform(-1, 1, (n, 101, 10)), np.broadcast_to(time_grid()[None, :, None], (n, 101, 1))], axis=-1)
    neighbours = np.stack([rng.permutation(np.delete(np.arange(n), i))[:p.train.near_pool] for i in range(n)])
    data = MotionDataset(rng.uniform(0, 1, (n, s, s, 4)).astype(np.float32), motions.astype(np.float32),
                         neighbours.astype(np.int32))
    camera = (np.array([[s, 0, s / 2], [0, s, s / 2], [0, 0, 1]], np.float32), s)
    vae_params = training.VAENet.from_preset(p).init(jax.random.key(0))
    specs = {"vae": (training.vae_spec(p), None), "ebm": (training.ebm_spec(p, camera=camera), vae_params),
             "dmo": (training.dmo_spec(p), vae_params)}
    result = {"preset": p.name, "image_size": s, "models": {}}
    total = 0.0
    for name, (spec, extra) in specs.items():
        tx = training.make_optimizer(spec.config)
        params = spec.init_fn(jax.random.key(1))
        state = training.TrainState.create(params, tx)
        step = jax.jit(training.make_train_step(spec, tx))
        times = []
        for i in range(repeats + 1):
            batch = data.batch(0, i, spec.batch_size, near=spec.near)
            t = time.perf_counter()
            state, metrics = step(state, batch, jax.random.key(i), extra)
            jax.block_until_ready(metrics)
            times.append(time.perf_counter() - t)
        compile_s, sec = times[0], statistics.median(times[1:])
        result["models"][name] = {"step_s": sec, "compile_s": compile_s, "steps": spec.steps,
                                  "train_s": sec * spec.steps, "batch": spec.batch_size}
        total += sec * spec.steps + compile_s
    result["total_s"] = total
    result["loadavg_1min_at_end"] = os.getloadavg()[0]
    return result


def format_training_step_benchmark(r: dict) -> str:
    lines = [f"training steps, preset {r['preset']!r} (image {r['image_size']}px), load avg {r['loadavg_1min_at_end']:.2f}",
             f"{'model':<6}{'step s':>9}{'compile s':>11}{'steps':>8}{'train s':>10}"]
    for name, m in r["models"].items():
        lines.append(f"{name:<6}{m['step_s']:>9.3f}{m['compile_s']:>11.1f}{m['steps']:>8}{m['train_s']:>10.0f}")
    lines.append(f"total incl. compile: {r['total_s']:.0f} s ({r['total_s'] / 60:.1f} min)")
    return "\n".join(lines)
