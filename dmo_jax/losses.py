"""Losses and negative samplers of docs/method.md ("Training"): VAE, EBM InfoNCE, DMO unroll.

All functions are pure and jit-able; ``images [B, S, S, 4]``, ``motions [B, 101, 11]``.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.motion import GRASP, ROT6D, UV, Z, camera_positions, rot6d_to_matrix

from .config import TrainConfig

NEGATIVE_MODES = ("in-data+vae", "only-vae")


def motion_errors(pred: jnp.ndarray, target: jnp.ndarray) -> dict[str, jnp.ndarray]:
    """Per-key mean squared errors (rotation as Gram–Schmidt matrices), averaged over all axes."""
    return {
        "uv": jnp.mean((pred[..., UV] - target[..., UV]) ** 2),
        "z": jnp.mean((pred[..., Z] - target[..., Z]) ** 2),
        "rotation": jnp.mean((rot6d_to_matrix(pred[..., ROT6D]) - rot6d_to_matrix(target[..., ROT6D])) ** 2),
        "grasp": jnp.mean((pred[..., GRASP] - target[..., GRASP]) ** 2),
    }


def motion_loss(pred: jnp.ndarray, target: jnp.ndarray, uv_weight: float = 10.0) -> jnp.ndarray:
    """MSE(rotation matrices) + uv_weight * MSE(uv) + MSE(z) + MSE(grasp)."""
    e = motion_errors(pred, target)
    return e["rotation"] + uv_weight * e["uv"] + e["z"] + e["grasp"]


# --------------------------------------------------------------------------- VAE
def vae_loss(vae, params, motions, key, cfg: TrainConfig, step):
    """Reconstruction through a posterior sample + ``vae_kl_weight`` * KL(q(z|x) || N(0, I)).

    With ``cfg.vae_kl_warmup`` > 0 the KL weight rises linearly from 0 at ``step`` 0 to
    ``vae_kl_weight`` at ``vae_kl_warmup``: with the full weight from the start, a decoder that
    begins at the mean pose can settle there and ignore the latent (posterior collapse)."""
    k_eps, k_drop = jax.random.split(key)
    mu, logvar = vae.encode(params, motions, train=True, rng=k_drop)
    z = mu + jnp.exp(0.5 * logvar) * jax.random.normal(k_eps, mu.shape)
    recon = vae.decode(params, z, train=True, rng=jax.random.fold_in(k_drop, 1))
    rec = motion_loss(recon, motions, cfg.uv_weight)
    kl = jnp.mean(jnp.sum(-0.5 * (1 + logvar - mu**2 - jnp.exp(logvar)), axis=-1))
    weight = cfg.vae_kl_weight
    if cfg.vae_kl_warmup > 0:
        weight = weight * jnp.minimum(1.0, jnp.asarray(step, jnp.float32) / cfg.vae_kl_warmup)
    return rec + weight * kl, {"recon": rec, "kl": kl}


# --------------------------------------------------------------------------- EBM
def ebm_candidates(vae, vae_params, motions, key, cfg: TrainConfig, negatives: str = "in-data+vae", near=None):
    """Per image: the positive first, then negatives -> ``[B, 1 + K, 101, 11]``.

    ``in-data+vae``: ``ebm_gt_negatives`` ground-truth motions of *other* images in the batch
    (with replacement) + ``ebm_vae_negatives`` VAE samples at ``vae_negative_sigma`` decoded
    from batch motions and shuffled across the batch. ``only-vae``: all K negatives from the
    VAE (paper Table 4 b).

    ``cfg.ebm_near_negatives`` > 0 (``in-data+vae`` only) draws that many of the in-data
    negatives, without replacement, from ``near [B, P, 101, 11]``, each positive's P nearest
    other training motions (``MotionDataset.batch(near=P)``): the bank motions that compete
    with the positive at prediction.
    """
    if negatives not in NEGATIVE_MODES:
        raise ValueError(f"unknown negatives {negatives!r}; expected one of {NEGATIVE_MODES}")
    b = motions.shape[0]
    k_gt, k_vae, k_perm = jax.random.split(key, 3)
    n_gt = cfg.ebm_gt_negatives if negatives == "in-data+vae" else 0
    n_vae = cfg.ebm_vae_negatives + (cfg.ebm_gt_negatives - n_gt)
    n_near = cfg.ebm_near_negatives if n_gt else 0
    parts = [motions[:, None]]
    if n_near:
        if near is None or near.shape[1] < n_near:
            raise ValueError(f"{n_near} near negatives need each positive's nearest motions (near [B, P >= "
                             f"{n_near}, 101, 11]), got {None if near is None else near.shape}")
        # a key of their own, so the random in-data and VAE negatives keep theirs
        k_near = jax.random.fold_in(key, 5)
        pick = jnp.argsort(jax.random.uniform(k_near, near.shape[:2]), axis=1)[:, :n_near]
        parts.append(jnp.take_along_axis(near, pick[:, :, None, None], axis=1))
    if n_gt - n_near:
        if b < 2:
            raise ValueError("in-data negatives need a batch of at least 2 images")
        offset = jax.random.randint(k_gt, (b, n_gt - n_near), 1, b)  # never 0: never the image's own motion
        parts.append(motions[(jnp.arange(b)[:, None] + offset) % b])
    samples = vae.sample_around(vae_params, motions, k_vae, cfg.vae_negative_sigma, num_samples=n_vae)
    flat = samples.reshape((b * n_vae,) + motions.shape[1:])
    parts.append(jax.random.permutation(k_perm, flat).reshape((b, n_vae) + motions.shape[1:]))
    return jax.lax.stop_gradient(jnp.concatenate(parts, axis=1))


def graded_targets(candidates, intrinsics, image_size: int, scale: float) -> jnp.ndarray:
    """``[B, 1 + K]`` target distribution over ``candidates [B, 1 + K, 101, 11]``:
    softmax(-d / ``scale``), d each candidate's mean 3-D pose distance (metres) from the
    positive (index 0). A candidate ``scale`` farther than another gets e times less mass."""
    pos = camera_positions(candidates, intrinsics, image_size)
    dist = jnp.mean(jnp.linalg.norm(pos - pos[:, :1], axis=-1), axis=-1)
    return jax.nn.softmax(-dist / scale, axis=-1)


def ebm_loss(ebm, params, images, candidates, key, targets=None):
    """InfoNCE (temperature 1): cross-entropy of softmax(-E) with the positive (index 0) as
    target, or with ``targets [B, 1 + K]`` (a distribution, e.g. :func:`graded_targets`).
    ``candidates [B, 1 + K, 101, 11]``. Metrics: loss, top-1 accuracy."""
    k_enc, k_head = jax.random.split(key)
    feature = ebm.encode(params, images, train=True, rng=k_enc)
    keys = jax.random.split(k_head, images.shape[0])
    energies = jax.vmap(lambda f, m, k: ebm.energy(params, f, m, train=True, rng=k))(feature, candidates, keys)
    logp = jax.nn.log_softmax(-energies, axis=-1)
    accuracy = jnp.mean(jnp.argmin(energies, axis=-1) == 0)
    if targets is None:
        return -jnp.mean(logp[:, 0]), {"top1": accuracy}
    return -jnp.mean(jnp.sum(targets * logp, axis=-1)), {"top1": accuracy}


def ebm_energies(ebm, params, images, candidates, images_per_chunk: int = 4) -> jnp.ndarray:
    """Energies ``[N, K]`` of each image's ``candidates [N, K, 101, 11]`` (inference mode).

    The heads run ``images_per_chunk`` images at a time: all 100 held-out images' 64 candidates at
    once needed over 20 GB for the w/o-concat variant's 202-token attention."""
    feature = ebm.encode(params, images)
    return jax.lax.map(lambda fm: ebm.energy(params, *fm), (feature, candidates), batch_size=images_per_chunk)


def ebm_eval(ebm, params, images, candidates, images_per_chunk: int = 4):
    """Held-out top-1: fraction of images whose positive has the lowest energy of its candidates."""
    energies = ebm_energies(ebm, params, images, candidates, images_per_chunk)
    return {"top1": jnp.mean(jnp.argmin(energies, axis=-1) == 0)}


# --------------------------------------------------------------------------- DMO
def dmo_inputs(vae, vae_params, motions, key, cfg: TrainConfig) -> jnp.ndarray:
    """The DMO's perturbed inputs ``[B, 101, 11]`` for clean ``motions [B, 101, 11]``: VAE samples at
    ``cfg.dmo_input_sigma``, or with ``cfg.dmo_inputs == "offset"`` the motions moved by the
    samples' difference from the decoding of the posterior mean (grasp clipped to [0, 1])."""
    samples = vae.sample_around(vae_params, motions, key, cfg.dmo_input_sigma)
    if cfg.dmo_inputs == "offset":
        samples = motions + samples - vae.decode(vae_params, vae.encode(vae_params, motions)[0])
        samples = samples.at[..., GRASP].set(jnp.clip(samples[..., GRASP], 0.0, 1.0))
    return jax.lax.stop_gradient(samples)


def dmo_unroll(dmo, params, feature, motions, steps: int, train: bool = False, key=None):
    """Apply the DMO ``steps`` times to ``motions [n, 101, 11]`` reusing one ``F [H, W, C]``;
    returns every step's output ``[steps, n, 101, 11]``."""

    def body(m, k):
        out = dmo.refine(params, feature, m, train=train, rng=k if train else None)
        return out, out

    keys = jax.random.split(key if key is not None else jax.random.key(0), steps)
    _, outs = jax.lax.scan(body, motions, keys)
    return outs


def dmo_loss(dmo, params, images, inputs, targets, key, steps: int, uv_weight: float = 10.0):
    """Mean over the ``steps`` unrolled outputs of the motion loss against the clean targets;
    gradients flow through the whole unroll; F is computed once per image and reused."""
    k_enc, k_head = jax.random.split(key)
    feature = dmo.encode(params, images, train=True, rng=k_enc)
    keys = jax.random.split(k_head, images.shape[0])
    outs = jax.vmap(lambda f, m, k: dmo_unroll(dmo, params, f, m[None], steps, True, k)[:, 0])(feature, inputs, keys)
    per_step = jax.vmap(lambda o: motion_loss(o, targets, uv_weight), in_axes=1)(outs)
    return jnp.mean(per_step), {"first_step": per_step[0], "last_step": per_step[-1]}


def dmo_position_change(dmo, params, images, starts, targets, steps: int, intrinsics, image_size: int):
    """The DMO on ``starts [B, k, 101, 11]`` (e.g. each image's nearest bank motions) against
    ``targets [B, 101, 11]``: mean 3-D position error before and after ``steps`` refinements
    (``near_position_before`` / ``near_position_after``, metres)."""
    feature = dmo.encode(params, images)
    outs = jax.vmap(lambda f, m: dmo_unroll(dmo, params, f, m, steps)[-1])(feature, starts)
    error = jax.vmap(jax.vmap(lambda m, t: position_error(m, t, intrinsics, image_size), (0, None)))
    return {"near_position_before": jnp.mean(error(starts, targets)),
            "near_position_after": jnp.mean(error(outs, targets))}


def position_error(pred, target, intrinsics, image_size: int) -> jnp.ndarray:
    """Mean 3-D distance (metres) between the poses' positions, recovered from (uv, z) with K."""
    offsets = camera_positions(pred, intrinsics, image_size) - camera_positions(target, intrinsics, image_size)
    return jnp.mean(jnp.linalg.norm(offsets, axis=-1))


def dmo_eval(dmo, params, images, inputs, targets, steps: int, intrinsics, image_size: int, unroll: int = 1):
    """Held-out errors before and after ``steps`` refinements: per key (MSE) and the mean
    3-D position error in metres (``position_before`` / ``position_after``); with
    ``unroll > steps`` also ``position_after_unroll`` after ``unroll`` refinements."""
    feature = dmo.encode(params, images)
    n = max(steps, unroll)
    outs = jax.vmap(lambda f, m: dmo_unroll(dmo, params, f, m[None], n)[:, 0], out_axes=1)(feature, inputs)
    before, after = motion_errors(inputs, targets), motion_errors(outs[steps - 1], targets)
    before["position"] = position_error(inputs, targets, intrinsics, image_size)
    after["position"] = position_error(outs[steps - 1], targets, intrinsics, image_size)
    metrics = {f"{k}_before": v for k, v in before.items()}
    metrics.update({f"{k}_after": v for k, v in after.items()})
    if unroll > steps:
        metrics["position_after_unroll"] = position_error(outs[-1], targets, intrinsics, image_size)
    return metrics
