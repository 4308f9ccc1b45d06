"""Mined negatives: the training motions the EBM itself ranks first for each training image.

At prediction the EBM ranks the whole bank, and its first choice is wrong where some motion far
from the scene's scores lower than the motions near it. On put_knife_on_chopping_board these are
motions that visit the knife and the board in the reverse order: their poses lie far from the
positive's, so neither the nearest-motion negatives (``dmo_jax.neighbours``) nor random ones
show them to the EBM. With ``TrainConfig.ebm_mined_steps`` the EBM, once trained for its
``ebm_steps``, ranks the bank for every training image as :func:`~dmo_jax.inference.predict`
does (with the preset's ``mining_coarse`` scoring where it has one) and trains on, drawing its
near negatives from that ranking. The ranking is stored beside the EBM's checkpoints, so a
resumed run trains on the same table::

    mined.npy    int32 [N, K]   per training image, its K lowest-energy *other* training motions
    mined.json   {k, fingerprint, step}: the training motions, K and the EBM's step it was made at
"""
from __future__ import annotations

import functools
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from envs.progress import Progress

from .config import Preset
from .data import MotionDataset, motions_fingerprint
from .inference import Models, applicable_coarse, bank_top_n, cache_bank, default_chunk, image_devices, map_over_images
from .networks import EBMNet

INDEX_FILE, INFO_FILE = "mined.npy", "mined.json"


@functools.partial(jax.jit, static_argnames=("preset", "k", "chunk", "coarse", "devices"))
def _ranked(params, images, cache, *, preset, k, chunk, coarse, devices):
    ebm = EBMNet(preset)
    return map_over_images(lambda p, c, image: bank_top_n(ebm, p, ebm.encode(p, image), c, k, chunk, coarse)[0],
                           devices, (params, cache), images)


def ranked_rivals(ebm_params, preset: Preset, dataset: MotionDataset, k: int, batch: int = 10,
                  log=print) -> np.ndarray:
    """``int32 [N, k]``: for each training image of ``dataset``, the indices of the ``k``
    lowest-energy training motions other than its own under the EBM, best first (the bank
    scored as ``preset.mining_coarse`` says, else as :func:`~dmo_jax.inference.predict` scores it)."""
    n = len(dataset)
    if not 1 <= k < n:
        raise ValueError(f"k must be in [1, {n - 1}] for {n} training motions, got {k}")
    chunk = default_chunk()
    cache = cache_bank(Models(ebm_params), jnp.asarray(dataset.motions), preset=preset, chunk=chunk)
    coarse = applicable_coarse(preset.mining_coarse or preset.coarse, k + 1, n)
    log(f"ranking the bank with the EBM for {n} training images (each image's {k} lowest-energy other motions)")
    progress, parts = Progress("rank the bank", n), []
    for i in range(0, n, batch):
        images = dataset.images[i:i + batch]
        parts.append(np.asarray(_ranked(ebm_params, jnp.asarray(images), cache, preset=preset, k=k + 1, chunk=chunk,
                                        coarse=coarse, devices=image_devices(len(images)))))
        progress.update(min(i + batch, n))
    progress.close()
    top = np.concatenate(parts)
    own = top == np.arange(n)[:, None]
    # drop each image's own motion where it was ranked, else the (k + 1)-th
    keep = ~own & (own.any(axis=1, keepdims=True) | (np.arange(k + 1) < k))
    return top[keep].reshape(n, k).astype(np.int32)


def stored_rivals(run_dir: Path, dataset: MotionDataset, k: int) -> np.ndarray | None:
    """The table :func:`store_rivals` wrote in ``run_dir`` for these training motions and ``k``,
    else None."""
    try:
        info = json.loads((run_dir / INFO_FILE).read_text())
        table = np.load(run_dir / INDEX_FILE)
    except (FileNotFoundError, ValueError):
        return None
    if info.get("k") != k or info.get("fingerprint") != motions_fingerprint(dataset.motions) \
            or table.shape != (len(dataset), k):
        return None
    return table


def store_rivals(run_dir: Path, table: np.ndarray, dataset: MotionDataset, step: int) -> None:
    """Write ``table`` atomically, the index file first (a crash leaves no info file that
    matches a half-written table)."""
    from envs.dataset import atomic_save, atomic_write_text

    (run_dir / INFO_FILE).unlink(missing_ok=True)
    atomic_save(run_dir / INDEX_FILE, table)
    atomic_write_text(run_dir / INFO_FILE, json.dumps(
        {"k": int(table.shape[1]), "fingerprint": motions_fingerprint(dataset.motions), "step": int(step)}))
