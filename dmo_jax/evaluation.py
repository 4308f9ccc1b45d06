"""Success of the learned methods in simulation (``bin/evaluate``).

For each test episode: rebuild the scene from its seed, predict from the stored first image
with the task's training motions as the bank (scored once; each method refines the same top
n), and execute the ranked candidates through ``envs.evaluation.run_episodes`` — the
next-lowest-energy candidate is tried when one is abandoned, at most n.
"""
from __future__ import annotations

import functools
import time
from typing import Sequence

import jax
import numpy as np

from envs.motion import Z
from envs.progress import Progress

from .config import Preset
from .data import network_image
from .inference import (METHODS_USING_R, CoarseRanking, OptimizerSettings, cache_bank, refine, resolve_coarse,
                        top_candidates)


def _padded_batches(images: np.ndarray, batch: int):
    """``(i, images[i:i + batch])`` with the last batch padded by repeating the last image, so
    every call has one shape (one compilation)."""
    pad = (-len(images)) % batch
    images = np.concatenate([images, np.repeat(images[-1:], pad, axis=0)]) if pad else images
    for i in range(0, len(images), batch):
        yield i, images[i:i + batch]


def predict_episodes(models, preset: Preset, methods: Sequence[str], images: np.ndarray, bank: np.ndarray,
                     settings: Sequence[tuple[int, int]], seed: int = 0, batch: int = 10,
                     optimizer: OptimizerSettings = OptimizerSettings(), coarse: CoarseRanking | None | str = "preset"):
    """Predict with each of ``methods`` at each ``(n, R)`` of ``settings`` for network
    ``images [E, S, S, 4]``, scoring the ``bank [N, 101, 11]`` (or its
    :class:`~dmo_jax.inference.BankCache`) once: its top ``max n``; a smaller n takes the first n
    of them; ``coarse`` as in :func:`~dmo_jax.inference.predict`.

    Returns ``(starts, predictions, seconds)``: the EBM's top ``max n`` bank motions per image
    ``[E, max n, 101, 11]``; per :func:`prediction_key` the ranked ``(candidates [E, K, 101, 11],
    energies [E, K])`` that :func:`~dmo_jax.inference.predict` returns with the same keys;
    the wall time of the bank scoring (``seconds["bank"]``) and of each prediction.
    """
    e, batch = len(images), min(batch, len(images))
    n_max = max(n for n, _ in settings)
    t0 = time.perf_counter()
    rankings = _rankings(models, preset, images, bank, n_max, batch, coarse)
    seconds = {"bank": time.perf_counter() - t0}
    starts = np.concatenate([np.asarray(r.motions) for r in rankings])[:e]
    predictions = {}
    for n, R in settings:
        for method in methods:
            slot = prediction_key(method, n, R)
            if slot in predictions:
                continue
            t0 = time.perf_counter()
            cands, energies = [], []
            progress = Progress(f"predict {method} n={n}" + ("" if slot[2] is None else f" R={R}"), e)
            for (i, x), ranking in zip(_padded_batches(images, batch), rankings):
                key = jax.random.fold_in(jax.random.key(seed), i)
                out = refine(models, x, ranking.first(n), key, preset=preset, method=method, R=R, settings=optimizer)
                cands.append(np.asarray(out.candidates))
                energies.append(np.asarray(out.energies))
                progress.update(min(i + batch, e))
            progress.close()
            predictions[slot] = (np.concatenate(cands)[:e], np.concatenate(energies)[:e])
            seconds[slot] = time.perf_counter() - t0
    return starts, predictions, seconds


def _rankings(models, preset: Preset, images: np.ndarray, bank, n: int, batch: int,
              coarse: CoarseRanking | None | str = "preset") -> list:
    """The bank's top ``n`` for ``images`` in batches of ``batch`` (the last one padded), computed
    before returning, with the bank's pose activations computed once for all of them
    (:func:`~dmo_jax.inference.cache_bank`, unless ``bank`` is one already). F is dropped (each
    refine call recomputes it): kept for every image it would take 64 MB per image at the paper
    preset."""
    bank = cache_bank(models, bank, preset=preset)
    rankings, progress = [], Progress("rank the bank", len(images))
    for i, x in _padded_batches(images, batch):
        ranking = top_candidates(models, x, bank, preset=preset, n=n, coarse=coarse)._replace(feature=None)
        rankings.append(jax.block_until_ready(ranking))
        progress.update(min(i + batch, len(images)))
    progress.close()
    return rankings


def coarse_recall(models, preset: Preset, images: np.ndarray, bank, starts: np.ndarray,
                  batch: int = 10) -> tuple[np.ndarray, float]:
    """How much of the full scoring of ``bank`` (motions or their cache) a coarse one kept: per
    image of ``images [E, S, S, 4]``, the fraction of the full ranking's top n that ``starts
    [E, n, 101, 11]`` (a coarse ranking's) holds, ``float [E]``; and the full scoring's wall time
    in seconds."""
    t0 = time.perf_counter()
    rankings = _rankings(models, preset, images, bank, starts.shape[1], min(batch, len(images)), coarse=None)
    seconds = time.perf_counter() - t0
    full = np.concatenate([np.asarray(r.motions) for r in rankings])[:len(images)]
    same = _among(full, starts)  # [E, n]: kept by the coarse one
    return same.mean(axis=1), seconds


def _among(motions: np.ndarray, pool: np.ndarray) -> np.ndarray:
    """bool ``[E, K]``: whether each of ``motions [E, K, 101, 11]`` is, byte for byte, one of its
    episode's ``pool [E, P, 101, 11]`` (compared as one bytes item per motion: no [E, K, P, ...]
    array, so K and P may be in the thousands)."""
    def rows(m):
        m = np.ascontiguousarray(m)
        return m.reshape(m.shape[:2] + (-1,)).view(np.dtype((np.void, m.shape[2] * m.shape[3] * m.itemsize)))[..., 0]

    return np.stack([np.isin(m, p) for m, p in zip(rows(motions), rows(pool))])


def prediction_key(method: str, n: int, R: int) -> tuple:
    """``(method, n, R)``, with R dropped (``None``) for methods that ignore it: they are
    predicted and executed once per n."""
    return method, n, R if method in METHODS_USING_R else None


@functools.partial(jax.jit, static_argnames="image_size")
def _candidate_errors(candidates, demonstrations, intrinsics, image_size: int):
    from .losses import position_error

    error = lambda m, d: position_error(m, d, intrinsics, image_size)  # noqa: E731
    return jax.vmap(jax.vmap(error, (0, None)))(candidates, demonstrations)


def candidate_errors(candidates: np.ndarray, demonstrations: np.ndarray, intrinsics, image_size: int) -> np.ndarray:
    """``float32 [E, K]``: the mean 3-D position error (metres, ``losses.position_error``) of each of
    ``candidates [E, K, 101, 11]`` against its scene's demonstration ``[E, 101, 11]``."""
    return np.asarray(_candidate_errors(np.asarray(candidates, np.float32), np.asarray(demonstrations, np.float32),
                                        np.asarray(intrinsics, np.float32), image_size))


def motion_diagnostics(starts: np.ndarray, candidates: np.ndarray, demonstrations: np.ndarray, intrinsics,
                       image_size: int, camera_pose: tuple | None = None, *, errors: np.ndarray | None = None) -> dict:
    """Where the ranked ``candidates [E, K, 101, 11]`` lie against the scenes' demonstrations,
    as mean 3-D position errors in metres (``losses.position_error``) averaged over episodes:
    ``first_error_m`` of the first-ranked candidate, ``start_error_m`` of the EBM's top bank
    motion, ``best_start_error_m`` of the closest of the ``n`` starts; ``first_depth_error_m``,
    the part of ``first_error_m`` along the camera's viewing axis (mean |z - z_demo|, which no
    pixel position shows); ``optimised_first``, the fraction of episodes whose first-ranked
    candidate is an optimised motion, not a start; and, for methods that optimise,
    ``mean_start_error_m`` / ``mean_optimised_error_m``, the mean error of the n starts and of
    the optimised motions (for the DMO at R = 1: the EBM's top n before and after one refinement).
    Given the camera's world ``camera_pose`` ``(position [3], rotation [3, 3])``,
    ``first_lowest_offset_m``: how much higher the first-ranked motion's lowest point lies than the
    demonstration's (signed, mean over episodes; what decides a press or a placement). ``errors
    [E, K]``: the candidates' :func:`candidate_errors`, where the caller has them already."""
    import jax.numpy as jnp

    start_errors = candidate_errors(starts, demonstrations, intrinsics, image_size)
    if errors is None:
        errors = candidate_errors(candidates, demonstrations, intrinsics, image_size)
    is_start = _among(candidates, starts)  # [E, K]
    depth_error = np.abs(candidates[:, 0, :, Z] - demonstrations[..., Z])
    out = {"first_error_m": round(float(np.mean(errors[:, 0])), 4),
           "first_depth_error_m": round(float(np.mean(depth_error)), 4),
           "start_error_m": round(float(np.mean(start_errors[:, 0])), 4),
           "best_start_error_m": round(float(np.mean(start_errors.min(axis=1))), 4),
           "optimised_first": round(float(np.mean(~is_start[:, 0])), 3)}
    if (~is_start).any():
        out["mean_start_error_m"] = round(float(np.mean(start_errors)), 4)
        out["mean_optimised_error_m"] = round(float(np.mean(errors[~is_start])), 4)
    if camera_pose is not None:
        from envs.motion import vector_to_pose

        position, rotation = (jnp.asarray(x, jnp.float32) for x in camera_pose)
        lowest = lambda m: np.asarray(vector_to_pose(jnp.asarray(m, jnp.float32), position, rotation,  # noqa: E731
                                                     jnp.asarray(intrinsics, jnp.float32), image_size)[0][..., 2]).min(-1)
        out["first_lowest_offset_m"] = round(float(np.mean(lowest(candidates[:, 0]) - lowest(demonstrations))), 4)
    return out


def candidate_outcomes(success: np.ndarray, is_start: np.ndarray, energies: np.ndarray, errors: np.ndarray) -> dict:
    """What a method's choice among its ranked candidates costs: given the ``success [E, K]`` of
    each candidate executed alone (``envs.evaluation.run_each_candidate``), which of them are
    bank motions (``is_start [E, K]``), their ``energies [E, K]`` and their distances from the
    demonstration (``errors [E, K]``, metres, :func:`candidate_errors`):
    ``some_candidate_solves`` / ``some_start_solves``, the fraction of scenes one of the candidates
    (of the starts) solves; ``start_success_rate`` / ``optimised_success_rate``, the mean success of
    a start and of an optimised motion; ``nearest_candidate_solves``, the fraction of scenes the
    candidate nearest the demonstration solves; ``success_by_error``, how often a candidate
    succeeds by its distance from the demonstration (:data:`ERROR_BINS`; how precise a motion
    must be); and the per-scene arrays, for other selection rules."""
    success, is_start = np.asarray(success, bool), np.asarray(is_start, bool)
    errors = np.asarray(errors, np.float64)
    nearest = success[np.arange(len(success)), errors.argmin(axis=1)]
    out = {"some_candidate_solves": round(float(success.any(axis=1).mean()), 4),
           "some_start_solves": round(float((success & is_start).any(axis=1).mean()), 4),
           "start_success_rate": round(float(success[is_start].mean()), 4),
           "nearest_candidate_solves": round(float(nearest.mean()), 4),
           "success_by_error": success_by_error(success, errors)}
    if (~is_start).any():
        out["optimised_success_rate"] = round(float(success[~is_start].mean()), 4)
    return {**out, "candidate_success": success.astype(int).tolist(),
            "candidate_is_start": is_start.astype(int).tolist(),
            "candidate_energies": np.round(np.asarray(energies, np.float64), 4).tolist(),
            "candidate_error_m": np.round(errors, 4).tolist()}


#: Upper edges (metres) of the distance bins of :func:`success_by_error`; the last bin is open.
ERROR_BINS = (0.005, 0.01, 0.015, 0.02, 0.03)


def success_by_error(success: np.ndarray, errors: np.ndarray) -> list[dict]:
    """Per bin of distance from the demonstration (:data:`ERROR_BINS`, then all farther), the
    candidates in it and the fraction of them that succeed: ``[{"from_m", "to_m" (None: open),
    "candidates", "success_rate" (None: no candidate)}]``, from ``success [E, K]`` and ``errors
    [E, K]`` (metres)."""
    success, errors = np.asarray(success, bool).ravel(), np.asarray(errors, np.float64).ravel()
    edges = (0.0,) + ERROR_BINS + (np.inf,)
    bins = []
    for low, high in zip(edges[:-1], edges[1:]):
        inside = (errors >= low) & (errors < high)
        bins.append({"from_m": low, "to_m": None if np.isinf(high) else high, "candidates": int(inside.sum()),
                     "success_rate": round(float(success[inside].mean()), 4) if inside.any() else None})
    return bins


def evaluate_methods(task_name: str, methods: Sequence[str], *, preset: Preset, workdir, data_root,
                     settings: Sequence[tuple[int, int]] = ((8, 1),), episodes: int | None = None,
                     backend: str = "auto",
                     negatives: str = "in-data+vae", dmo_train_steps: int | None = None, seed: int = 0,
                     viz_dir=None, coarse: CoarseRanking | None | str = "preset",
                     measure_recall: bool = False, each_candidate: bool = False) -> list[dict]:
    """Predict with each of ``methods`` at each ``(n, R)`` of ``settings`` on the first
    ``episodes`` test images of a task (the bank scored once for all) and execute.

    Returns one result per setting and method (settings outer; a method that ignores R once
    per n, with ``R`` None): the ``run_episodes`` result plus ``method``, ``n``, ``R``,
    ``predict_seconds`` (bank scoring + the method), :func:`motion_diagnostics` and ``coarse``,
    the bank scoring used (``coarse`` as in :func:`~dmo_jax.inference.predict`; ``[stride,
    keep]`` or None). With ``measure_recall`` and a coarse scoring the bank is also scored in
    full, untimed, for ``coarse_recall`` (:func:`coarse_recall`, mean over the scenes) and
    ``full_bank_seconds``. With ``each_candidate`` every one of a result's K ranked candidates is
    also executed alone (K times the execution), for :func:`candidate_outcomes`.
    """
    from envs import evaluation
    from envs.dataset import DatasetError, load_split

    from .workflow import load_models

    test = load_split(data_root, task_name, "test", preset.image_size)
    if test.meta["image_size"] != preset.image_size:
        raise DatasetError(f"{data_root}/{task_name} has {test.meta['image_size']}px images but preset "
                           f"{preset.name!r} needs {preset.image_size}px; use another --data directory")
    train = load_split(data_root, task_name, "train", preset.image_size)
    bank = np.asarray(train.motions, np.float32)
    models = load_models(workdir, task_name, preset, methods, negatives, dmo_train_steps, bank)
    episodes = evaluation.episodes_to_run(episodes, test, task_name, data_root)
    images = network_image(test.rgb[:episodes], test.depth[:episodes])
    t0 = time.perf_counter()
    cache = cache_bank(models, bank, preset=preset)  # once for the ranking and the recall's full scoring
    cache_seconds = time.perf_counter() - t0
    starts, predictions, seconds = predict_episodes(models, preset, methods, images, cache, settings, seed,
                                                    coarse=coarse)
    seconds["bank"] += cache_seconds
    coarse = resolve_coarse(preset, coarse, max(n for n, _ in settings), len(bank))
    extra = {"coarse": None if coarse is None else list(coarse)}
    if measure_recall and coarse is not None:
        recall, full_seconds = coarse_recall(models, preset, images, cache, starts)
        extra.update({"coarse_recall": round(float(recall.mean()), 4), "bank_seconds": round(seconds["bank"], 2),
                      "full_bank_seconds": round(full_seconds, 2)})
    intrinsics = np.asarray(test.meta["intrinsics"], np.float32)
    results = []
    for (method, n, R), (cands, energies) in predictions.items():
        result = evaluation.run_episodes(task_name, test, cands[:, :n], backend)
        if viz_dir is not None:
            from .visualize import save_episode_visuals

            label = f"{method}_n{n}" + ("" if R is None else f"_R{R}") if len(predictions) > 1 else ""
            save_episode_visuals(viz_dir, task_name, test, cands, energies, result, preset, label=label)
        errors = candidate_errors(cands, test.motions[:episodes], intrinsics, preset.image_size)
        diagnostics = motion_diagnostics(starts[:, :n], cands, test.motions[:episodes], intrinsics,
                                         preset.image_size, (test.meta["camera_position"], test.meta["camera_rotation"]),
                                         errors=errors)
        if each_candidate:
            diagnostics.update(candidate_outcomes(evaluation.run_each_candidate(task_name, test, cands, backend),
                                                  _among(cands, starts[:, :n]), energies, errors))
        results.append({"method": method, "n": n, "R": R, **result,
                        "predict_seconds": round(seconds["bank"] + seconds[(method, n, R)], 2), **diagnostics,
                        **extra})
    return results


def evaluate_method(task_name: str, method: str, *, n: int = 8, R: int = 1, **kwargs) -> dict:
    """:func:`evaluate_methods` for one method and one ``(n, R)``."""
    return evaluate_methods(task_name, [method], settings=[(n, R)], **kwargs)[0]


def ebm_heldout_misses(task_name: str, *, preset: Preset, workdir, data_root,
                       negatives: str = "in-data+vae") -> dict:
    """The held-out EBM ranking of ``bin/train_all`` (``training.heldout_ebm_candidates``), with
    every miss explained: the winning ``candidate``'s index, which kind of negative it is
    (``winner``: another scene's recorded motion, "in-data", or a VAE sample) and how far its
    poses lie from the positive's (``distance_m``, mean 3-D distance in metres); and, for every
    episode, how far the closest other scene's motion among its candidates lies
    (``nearest_in_data_m``): a near-tie no ranking at the image's resolution can be sure of."""
    import jax.numpy as jnp

    from . import losses, training
    from .networks import EBMNet
    from .workflow import load_models, load_task_data

    train, test, (intrinsics, size) = load_task_data(task_name, data_root, preset, generate=False)
    models = load_models(workdir, task_name, preset, "vaebm-l", negatives, bank=train.motions)
    ebm_params, vae_params = models.ebm, models.vae
    ebm = EBMNet(preset)
    cands = training.heldout_ebm_candidates(preset, vae_params, test.motions)

    score = jax.jit(functools.partial(losses.ebm_energies, ebm))
    energies = score(ebm_params, jnp.asarray(test.images), cands)
    winners = np.asarray(jnp.argmin(energies, axis=-1))
    distances = np.asarray(jax.jit(jax.vmap(jax.vmap(
        lambda c, pos: losses.position_error(c[None], pos[None], intrinsics, size), (0, None))))(cands, cands[:, 0]))
    misses = [{"episode": int(i), "candidate": int(winners[i]),
               "winner": "in-data" if winners[i] <= training.HELDOUT_GT_NEGATIVES else "vae",
               "distance_m": float(distances[i, winners[i]])} for i in np.flatnonzero(winners != 0)]
    nearest = distances[:, 1:training.HELDOUT_GT_NEGATIVES + 1].min(axis=1)
    return {"task": task_name, "episodes": len(winners), "top1": float(np.mean(winners == 0)), "misses": misses,
            "nearest_in_data_m": [round(float(d), 4) for d in nearest]}
