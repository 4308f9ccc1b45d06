"""Mined negatives: the training motions the EBM itself ranks first for each training image.

At prediction the EBM ranks the whole bank, and its first choice is wrong where some motion far
from the scene's scores lower than the motions near it. On put_knife_on_chopping_board these are
motions that visit the knife and the board in the reverse order: their poses lie far from the
positive's, so neither the nearest-motion negatives (``dmo_jax.neighbours``) nor random ones
show them to the EBM. With ``TrainConfig.ebm_mined_steps`` the EBM, once trained for its
``ebm_steps``, ranks the bank for every training image as :func:`~dmo_jax.inference.predict`
does (with the preset's ``mining_coarse`` scoring where it has one) and trains on, drawing its
near negatives from that ranking. With ``TrainConfig.ebm_executed_rivals`` = L the first L of each image's
rivals are also executed in that image's scene (:func:`rival_outcomes`), and the mined steps'
graded target counts a rival that succeeded as the positive and one that failed as wrong: the
EBM's first choice among its top 8 solves fewer scenes than the best of them, because lying close
to the demonstration is not the same as succeeding. The ranking is stored beside the EBM's
checkpoints, so a resumed run trains on the same table::

    mined.npy           int32 [N, K]  per training image, its K lowest-energy *other* training motions
    mined_outcomes.npy  bool [N, L]   whether each of the first L succeeded in the image's scene
    mined.json          {k, fingerprint, step, executed}: the training motions, K, the EBM's step
                        it was made at, and L (0: no outcomes)
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
from .inference import Models, applicable_coarse, bank_top_n, cache_bank, default_chunk
from .networks import EBMNet

INDEX_FILE, OUTCOME_FILE, INFO_FILE = "mined.npy", "mined_outcomes.npy", "mined.json"


@functools.partial(jax.jit, static_argnames=("preset", "k", "chunk", "coarse"))
def _ranked(params, images, cache, *, preset, k, chunk, coarse):
    ebm = EBMNet(preset)
    return jax.lax.map(lambda image: bank_top_n(ebm, params, ebm.encode(params, image), cache, k, chunk, coarse)[0],
                       images)


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
        parts.append(np.asarray(_ranked(ebm_params, jnp.asarray(dataset.images[i:i + batch]), cache, preset=preset,
                                        k=k + 1, chunk=chunk, coarse=coarse)))
        progress.update(min(i + batch, n))
    progress.close()
    top = np.concatenate(parts)
    own = top == np.arange(n)[:, None]
    # drop each image's own motion where it was ranked, else the (k + 1)-th
    keep = ~own & (own.any(axis=1, keepdims=True) | (np.arange(k + 1) < k))
    return top[keep].reshape(n, k).astype(np.int32)


def _stored_info(run_dir: Path, dataset: MotionDataset) -> dict | None:
    try:
        info = json.loads((run_dir / INFO_FILE).read_text())
    except (FileNotFoundError, ValueError):
        return None
    return info if isinstance(info, dict) and info.get("fingerprint") == motions_fingerprint(dataset.motions) else None


def stored_rivals(run_dir: Path, dataset: MotionDataset, k: int) -> np.ndarray | None:
    """The table :func:`store_rivals` wrote in ``run_dir`` for these training motions and ``k``,
    else None."""
    info = _stored_info(run_dir, dataset)
    if info is None or info.get("k") != k:
        return None
    try:
        table = np.load(run_dir / INDEX_FILE)
    except (FileNotFoundError, ValueError):
        return None
    return table if table.shape == (len(dataset), k) else None


def stored_outcomes(run_dir: Path, dataset: MotionDataset, executed: int) -> np.ndarray | None:
    """The outcomes ``bool [N, executed]`` :func:`store_rivals` wrote in ``run_dir`` for these training
    motions, else None."""
    info = _stored_info(run_dir, dataset)
    if info is None or info.get("executed") != executed:
        return None
    try:
        outcomes = np.load(run_dir / OUTCOME_FILE)
    except (FileNotFoundError, ValueError):
        return None
    return outcomes if outcomes.shape == (len(dataset), executed) and outcomes.dtype == bool else None


def store_rivals(run_dir: Path, table: np.ndarray, dataset: MotionDataset, step: int,
                 outcomes: np.ndarray | None = None) -> None:
    """Write ``table`` (and the ``outcomes [N, L]`` of its first L columns) atomically, the info
    file last (a crash leaves no info file that matches a half-written table)."""
    from envs.dataset import atomic_save, atomic_write_text

    (run_dir / INFO_FILE).unlink(missing_ok=True)
    atomic_save(run_dir / INDEX_FILE, table)
    if outcomes is not None:
        atomic_save(run_dir / OUTCOME_FILE, np.asarray(outcomes, bool))
    atomic_write_text(run_dir / INFO_FILE, json.dumps(
        {"k": int(table.shape[1]), "fingerprint": motions_fingerprint(dataset.motions), "step": int(step),
         "executed": 0 if outcomes is None else int(outcomes.shape[1])}))


def rival_outcomes(task_name: str, data_root, table: np.ndarray) -> np.ndarray:
    """``bool [N, L]``: whether the training motion ``table[i, j]`` succeeds when executed alone in
    training scene i of task ``task_name`` (rebuilt from its seed in ``data_root``)."""
    from envs.dataset import load_split
    from envs.evaluation import run_each_candidate

    train = load_split(data_root, task_name, "train")
    if len(train) != len(table):
        raise ValueError(f"{len(table)} rows of rivals for the {len(train)} training scenes of {task_name}")
    return run_each_candidate(task_name, train, np.asarray(train.motions)[table], progress=True)


def neighbour_outcomes(outcomes: np.ndarray, pool: int) -> np.ndarray:
    """``int8 [N, pool]`` for ``MotionDataset.neighbour_outcomes``: the ``outcomes [N, L]`` of the
    first L rivals (1 succeeded, 0 failed), -1 for the rest."""
    out = np.full((len(outcomes), pool), -1, np.int8)
    out[:, :outcomes.shape[1]] = outcomes
    return out
