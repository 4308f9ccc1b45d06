"""Success of the learned methods in simulation (``bin/evaluate``).

For each test episode: rebuild the scene from its seed, :func:`~dmo_jax.inference.predict`
from the stored first image with the task's training motions as the bank, and execute the
ranked candidates through ``envs.evaluation.run_episodes`` — the next-lowest-energy
candidate is tried when one is abandoned, at most n.
"""
from __future__ import annotations

import time

import jax
import numpy as np

from .config import Preset
from .data import network_image
from .inference import OptimizerSettings, predict


def predict_episodes(models, preset: Preset, method: str, images: np.ndarray, bank: np.ndarray, n: int, R: int,
                     seed: int = 0, batch: int = 10, settings: OptimizerSettings = OptimizerSettings()):
    """Ranked candidates ``[E, K, 101, 11]`` and energies ``[E, K]`` for network ``images [E, S, S, 4]``,
    ``batch`` images per :func:`predict` call (the last batch is padded, so one compilation)."""
    e = len(images)
    batch = min(batch, e)
    pad = (-e) % batch
    images = np.concatenate([images, np.repeat(images[-1:], pad, axis=0)]) if pad else images
    bank = jax.numpy.asarray(bank)
    cands, energies = [], []
    for i in range(0, len(images), batch):
        key = jax.random.fold_in(jax.random.key(seed), i)
        out = predict(models, images[i:i + batch], bank, key, preset=preset, method=method, n=n, R=R,
                      settings=settings)
        cands.append(np.asarray(out.candidates))
        energies.append(np.asarray(out.energies))
    return np.concatenate(cands)[:e], np.concatenate(energies)[:e]


def evaluate_method(task_name: str, method: str, *, preset: Preset, workdir, data_root, n: int = 8, R: int = 1,
                    episodes: int = 100, backend: str = "auto", negatives: str = "in-data+vae",
                    dmo_train_iters: int | None = None, seed: int = 0, viz_dir=None) -> dict:
    """Predict with ``method`` on the first ``episodes`` test images of a task and execute.

    Returns the ``run_episodes`` result plus ``method``, ``n``, ``R``, ``predict_seconds``.
    """
    from envs import evaluation
    from envs.dataset import DatasetError, load_split

    from .workflow import load_models

    test = load_split(data_root, task_name, "test")
    if test.meta["image_size"] != preset.image_size:
        raise DatasetError(f"{data_root}/{task_name} has {test.meta['image_size']}px images but preset "
                           f"{preset.name!r} needs {preset.image_size}px; use another --data directory")
    bank = np.asarray(load_split(data_root, task_name, "train").motions, np.float32)
    models = load_models(workdir, task_name, preset, method, negatives, dmo_train_iters)
    episodes = min(episodes, len(test))
    images = network_image(test.rgb[:episodes], test.depth[:episodes])
    t0 = time.perf_counter()
    cands, energies = predict_episodes(models, preset, method, images, bank, n, R, seed)
    predict_seconds = time.perf_counter() - t0
    result = evaluation.run_episodes(task_name, test, cands[:, :n], backend)
    if viz_dir is not None:
        from .visualize import save_episode_visuals

        save_episode_visuals(viz_dir, task_name, test, cands, energies, result, preset)
    return {"method": method, "n": n, "R": R, **result, "predict_seconds": round(predict_seconds, 2)}


def ebm_heldout_misses(task_name: str, *, preset: Preset, workdir, data_root,
                       negatives: str = "in-data+vae") -> dict:
    """The held-out EBM ranking of ``bin/train_all`` (``training.heldout_ebm_candidates``), with
    every miss explained: which kind of negative won and how far its poses lie from the
    positive's (mean 3-D distance, metres)."""
    import jax.numpy as jnp

    from . import losses, training
    from .networks import EBMNet
    from .workflow import RunPaths, load_task_data

    _, test, (intrinsics, size) = load_task_data(task_name, data_root, preset, generate=False)
    paths = RunPaths.of(workdir, task_name, preset)
    ebm_params, _ = training.load_params(paths.ebm(preset.variant, negatives), training.ebm_spec(preset, negatives))
    vae_params, _ = training.load_params(paths.vae(), training.vae_spec(preset))
    ebm = EBMNet(preset)
    cands = training.heldout_ebm_candidates(preset, vae_params, test.motions)
    feature = ebm.encode(ebm_params, jnp.asarray(test.images))
    energies = jax.vmap(lambda f, c: ebm.energy(ebm_params, f, c))(feature, cands)
    winners = np.asarray(jnp.argmin(energies, axis=-1))
    misses = []
    for i in np.flatnonzero(winners != 0):
        w = int(winners[i])
        misses.append({"episode": int(i), "winner": "in-data" if w <= 31 else "vae",
                       "distance_m": float(losses.position_error(cands[i, w][None], cands[i, 0][None], intrinsics, size))})
    return {"task": task_name, "episodes": len(winners), "top1": float(np.mean(winners == 0)), "misses": misses}
