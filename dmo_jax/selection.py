"""The selection head: a learned choice among the DMO's candidates, in place of the lowest energy.

Among the EBM's top 8 bank motions and their refinements some motion solves 94-100 % of the
scenes of every task, but the lowest-energy one solves 63-100 %: what limits success is the choice,
and the energy, trained to pick the scene's own motion among others, ranks the near candidates by
closeness, which is a weak guide to which of them succeeds. With ``TrainConfig.selection_scenes``
> 0, once the DMO is trained, the candidates :func:`~dmo_jax.inference.predict` makes for that
many training scenes (the bank without the scene's own motion, as at prediction) are executed
alone in their scene, and a linear score of each candidate's energy and of its EBM pose tokens
averaged over each of ``PHASES`` consecutive parts of the motion
(:meth:`~dmo_jax.networks.EBMNet.pooled_and_phases`; ``PHASES * w + 1`` weights) is fitted to put
a succeeding candidate first: a listwise loss, ``-log`` of the softmax mass of the scene's succeeding
candidates, from weights that rank by energy alone and with an L2 pull back to them. The DMO's
prediction then ranks its candidates by that score (the networks are unchanged; ``sort`` and the
other methods still rank by energy). Stored per EBM and DMO as one JSON file beside them::

    {"weights": [PHASES * w + 1 floats], "phases", "fingerprint": the training motions', "scenes", ...}
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from envs.progress import Progress

from .config import Preset
from .data import motions_fingerprint

#: Pull of the weights back to the energy's ranking, on standardised inputs: in 5-fold
#: cross-validation on take_plate's first 300 training scenes the selected candidate succeeded
#: in 88-89 % of them for any pull from 0.003 to 0.3 (85 % by energy), 86 % at 1.
L2 = 0.03
#: Parts of the motion over which the head averages the EBM's pose tokens (BENCHMARKS.md, "The head
#: reads the motion in eight parts", against the mean over the whole motion). 2, 4 and 16 parts,
#: fitted to the same executed candidates of take_plate and put_umbrella, chose no better than 8.
PHASES = 8
_FIT_STEPS, _FIT_RATE = 2000, 0.05


def selection_scores(weights: jax.Array, phases: jax.Array, energies: jax.Array) -> jax.Array:
    """``weights [P * w + 1]``, candidates' phase tokens ``phases [..., K, P, w]`` and ``energies
    [..., K]`` -> scores ``[..., K]``, higher is the better candidate."""
    return phases.reshape(phases.shape[:-2] + (-1,)) @ weights[:-1] + energies * weights[-1]


def fit_weights(phases: np.ndarray, energies: np.ndarray, success: np.ndarray, l2: float = L2) -> np.ndarray:
    """Weights ``float32 [P * w + 1]`` that put a succeeding candidate first, from the phase tokens
    ``phases [M, K, P, w]``, ``energies [M, K]`` and ``success [M, K]`` (bool) of M scenes' K
    candidates. Scenes where every candidate or none succeeds carry no choice and are left out;
    with none left the weights rank by energy alone."""
    features = np.reshape(phases, np.shape(phases)[:2] + (-1,))
    x = np.concatenate([features, energies[..., None]], axis=-1).astype(np.float64)
    s = np.asarray(success, np.float64)
    # scaled by the spread within a scene, the only one a choice among its candidates sees
    scale = (x - x.mean(axis=1, keepdims=True)).reshape(-1, x.shape[-1]).std(axis=0) + 1e-6
    w0 = np.zeros(x.shape[-1])
    w0[-1] = -3.0  # softmax(-3 standardised energies): the energy's choice
    useful = (s.max(axis=1) > 0) & (s.min(axis=1) < 1)
    x, s, w = x[useful] / scale, s[useful], w0.copy()
    for _ in range(_FIT_STEPS if len(x) else 0):
        z = x @ w
        p = np.exp(z - z.max(axis=1, keepdims=True))
        p /= p.sum(axis=1, keepdims=True)
        q = p * s
        q /= q.sum(axis=1, keepdims=True)  # the softmax restricted to the succeeding candidates
        w -= _FIT_RATE * (np.einsum("mk,mkd->d", p - q, x) / len(x) + l2 * (w - w0))
    weights = (w / scale).astype(np.float32)
    if not np.all(np.isfinite(weights)):
        raise FloatingPointError("the selection head's weights are not finite")
    return weights


def training_candidates(models, preset: Preset, images: np.ndarray, bank: np.ndarray, own: np.ndarray,
                        n: int = 8, R: int = 1, batch: int = 10, seed: int = 0):
    """The DMO's candidates for training ``images [M, S, S, 4]`` as prediction makes them, from the
    bank ``[N, 101, 11]`` without each image's own motion (index ``own [M]``): ``(candidates
    [M, K, 101, 11], energies [M, K], phases [M, K, PHASES, w])``, K = n (R + 1), ranked by energy."""
    from .inference import Ranking, cache_bank, refine, top_candidates
    from .networks import EBMNet

    ebm, cache = EBMNet(preset), cache_bank(models, jnp.asarray(bank), preset=preset)
    # from each image's F, kept by the ranking
    phases_of = jax.jit(jax.vmap(lambda p, f, m: ebm.pooled_and_phases(p, f, m, PHASES)[1], (None, 0, 0)))
    cands, energies, phases = [], [], []
    progress = Progress("the DMO's candidates", len(images))
    for i in range(0, len(images), batch):
        x, mine = images[i:i + batch], own[i:i + batch]
        ranking = top_candidates(models, x, cache, preset=preset, n=n + 1)
        index = np.asarray(_bank_index(ranking.motions, bank))
        keep = np.argsort(index == mine[:, None], axis=1, kind="stable")[:, :n]  # the own motion last, dropped
        start = Ranking(jnp.take_along_axis(ranking.motions, keep[:, :, None, None], 1),
                        jnp.take_along_axis(ranking.energies, keep, 1), ranking.feature)
        out = refine(models, x, start, jax.random.fold_in(jax.random.key(seed), i), preset=preset, method="dmo", R=R)
        cands.append(np.asarray(out.candidates))
        energies.append(np.asarray(out.energies))
        phases.append(np.asarray(phases_of(models.ebm, ranking.feature, out.candidates)))
        progress.update(min(i + batch, len(images)))
    progress.close()
    return np.concatenate(cands), np.concatenate(energies), np.concatenate(phases)


def _bank_index(motions: jax.Array, bank: np.ndarray) -> np.ndarray:
    """``int [B, k]``: which bank motion each of ``motions [B, k, 101, 11]`` is (the ranking returns
    bank motions unchanged, so byte for byte)."""
    where = {m.tobytes(): i for i, m in enumerate(np.asarray(bank, np.float32))}
    motions = np.asarray(motions, np.float32)
    return np.array([where[m.tobytes()] for m in motions.reshape((-1,) + motions.shape[2:])]).reshape(motions.shape[:2])


def train_selection(task_name: str, models, preset: Preset, train, path: Path, log=print) -> dict:
    """Fit (or load) the selection head of these networks on the first ``preset.train.selection_scenes``
    scenes (all of them where there are fewer) of the training split ``train``
    (``envs.dataset.Split``), stored at ``path`` (named after the networks and the scene count,
    ``RunPaths.selection``); returns its summary."""
    from envs.dataset import atomic_write_text
    from envs.evaluation import run_each_candidate

    from .data import network_image

    bank = np.asarray(train.motions, np.float32)
    scenes = min(preset.train.selection_scenes, len(bank))
    if scenes < 1:
        raise ValueError(f"selection_scenes must be positive to fit a selection head, got {scenes}")
    stored = _stored(path, bank)
    if stored is not None:
        return {k: v for k, v in stored.items() if k not in ("weights", "fingerprint")}
    t0 = time.perf_counter()
    log(f"[{task_name}] selection head: the DMO's candidates for {scenes} training scenes, each executed there")
    images = network_image(train.rgb[:scenes], train.depth[:scenes])
    cands, energies, phases = training_candidates(models, preset, images, bank, np.arange(scenes))
    success = run_each_candidate(task_name, train, cands, progress="execute the candidates")
    weights = fit_weights(phases, energies, success)
    chosen = np.argmax(selection_scores(weights, phases, energies), axis=1)
    summary = {"scenes": scenes, "phases": PHASES, "l2": L2,
               "candidate_succeeds": round(float(success.mean()), 4),
               "some_candidate_succeeds": round(float(success.any(axis=1).mean()), 4),
               "lowest_energy_succeeds": round(float(success[:, 0].mean()), 4),
               "selected_succeeds": round(float(success[np.arange(scenes), chosen].mean()), 4),
               "seconds": round(time.perf_counter() - t0, 1)}
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps({**summary, "fingerprint": motions_fingerprint(bank),
                                        "weights": weights.tolist()}))
    return summary


def _stored(path: Path, bank: np.ndarray) -> dict | None:
    try:
        stored = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    # a head of other data, or of an older feature layout (no "phases": the mean over the motion), is not this one
    same = stored.get("fingerprint") == motions_fingerprint(bank) and stored.get("phases") == PHASES
    return stored if same else None


def load_weights(path: Path, bank: np.ndarray) -> np.ndarray:
    """The weights :func:`train_selection` stored at ``path`` for these training motions;
    ``ValueError`` naming the file when there are none."""
    stored = _stored(path, bank)
    if stored is None:
        raise ValueError(f"no selection head for these networks, data and {PHASES} phases in {path}: "
                         "train it first (bin/train_all)")
    return np.asarray(stored["weights"], np.float32)
