"""Training data: network images, the RGB augmentation, and deterministic batches.

Network image: ``[S, S, 4]`` float32 — RGB scaled to [0, 1], and metric depth mapped
linearly from [DEPTH_NEAR, DEPTH_FAR] metres to [0, 1] (clipped; the table and the arm
lie between 1.1 and 2.6 m from the front camera, the background beyond is 1).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from envs.motion import count_non_finite

DEPTH_NEAR, DEPTH_FAR = 0.5, 3.0


def network_image(rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``rgb uint8 [..., S, S, 3]``, ``depth float32 [..., S, S]`` (metres) -> ``float32 [..., S, S, 4]``."""
    rgb = np.asarray(rgb)
    if not np.issubdtype(np.asarray(depth).dtype, np.floating):
        raise ValueError(f"depth must be floating-point metres, got {np.asarray(depth).dtype} (integer depth is "
                         "often millimetres: divide by 1000 first)")
    depth = np.asarray(depth, np.float32)
    if rgb.dtype != np.uint8 or rgb.shape[-1] != 3 or rgb.shape[:-1] != depth.shape:
        raise ValueError(
            f"expected rgb uint8 [..., S, S, 3] and depth [..., S, S], got {rgb.dtype}{list(rgb.shape)} "
            f"and {depth.dtype}{list(depth.shape)}"
        )
    bad = count_non_finite(depth)
    if bad:
        raise ValueError(f"depth contains {bad} NaN or inf value(s); expected finite metric depth in metres")
    d = np.clip((depth - DEPTH_NEAR) / (DEPTH_FAR - DEPTH_NEAR), 0.0, 1.0)
    return np.concatenate([rgb.astype(np.float32) / 255.0, d[..., None]], axis=-1)


# --------------------------------------------------------------------------- augmentation
def _box_blur(rgb):
    k = jnp.ones((3, 3), rgb.dtype) / 9.0
    pad = jnp.pad(rgb, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w, _ = rgb.shape
    return sum(k[i, j] * pad[i : i + h, j : j + w] for i in range(3) for j in range(3))


def _jpeg_like(rgb, key):
    """Compression-like loss: 8x8 block means blended back in, then 5-bit quantisation."""
    h, w, c = rgb.shape
    b = 8 if h % 8 == 0 and w % 8 == 0 else 1
    blocks = rgb.reshape(h // b, b, w // b, b, c).mean(axis=(1, 3), keepdims=True)
    coarse = jnp.broadcast_to(blocks, (h // b, b, w // b, b, c)).reshape(h, w, c)
    mix = jax.random.uniform(key, (), minval=0.2, maxval=0.6)
    return jnp.round(((1 - mix) * rgb + mix * coarse) * 31.0) / 31.0


def _coarse_dropout(rgb, key):
    h, w, _ = rgb.shape
    k1, k2 = jax.random.split(key)
    size = jnp.maximum(h // 8, 1)
    centres = jax.random.randint(k1, (4, 2), 0, jnp.array([h, w]))
    ys, xs = jnp.arange(h)[:, None], jnp.arange(w)[None, :]
    holes = jnp.zeros((h, w), bool)
    for i in range(4):
        holes |= (jnp.abs(ys - centres[i, 0]) < size // 2 + 1) & (jnp.abs(xs - centres[i, 1]) < size // 2 + 1)
    keep = jax.random.bernoulli(k2, 0.5, (4,)).any()  # sometimes no hole at all
    return jnp.where(holes[..., None] & keep, 0.0, rgb)


def augment_image(image: jnp.ndarray, key: jax.Array) -> jnp.ndarray:
    """docs/method.md's RGB augmentation on one ``[S, S, 4]`` image: one of {Gaussian noise
    sigma 0.05, JPEG-like loss, brightness +-40/255, 3x3 box blur, coarse dropout, identity},
    chosen uniformly. Depth is never changed."""
    rgb, depth = image[..., :3], image[..., 3:]
    k_choice, k_op = jax.random.split(key)
    ops = [
        lambda x: x + 0.05 * jax.random.normal(k_op, x.shape, x.dtype),
        lambda x: _jpeg_like(x, k_op),
        lambda x: x + jax.random.uniform(k_op, (), minval=-40 / 255, maxval=40 / 255),
        _box_blur,
        lambda x: _coarse_dropout(x, k_op),
        lambda x: x,
    ]
    out = jax.lax.switch(jax.random.randint(k_choice, (), 0, len(ops)), ops, rgb)
    return jnp.concatenate([jnp.clip(out, 0.0, 1.0), depth], axis=-1)


def augment_batch(images: jnp.ndarray, key: jax.Array) -> jnp.ndarray:
    """:func:`augment_image` on ``[B, S, S, 4]`` with an independent choice per image."""
    return jax.vmap(augment_image)(images, jax.random.split(key, images.shape[0]))


# --------------------------------------------------------------------------- batches
def motions_fingerprint(motions: np.ndarray) -> str:
    """A short hash of training ``motions [N, 101, 11]`` (as float32): which data a network learnt from."""
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(motions, np.float32).tobytes()).hexdigest()[:16]


@dataclasses.dataclass(frozen=True)
class MotionDataset:
    """A task split in memory: ``images [N, S, S, 4]`` float32, ``motions [N, 101, 11]`` float32,
    and optionally ``neighbours [N, K]`` int32, the indices of each motion's nearest training
    motions, nearest first (``dmo_jax.neighbours``; for the training split the *other* training
    motions, which :meth:`batch` with ``near`` needs)."""

    images: np.ndarray
    motions: np.ndarray
    neighbours: np.ndarray | None = None

    @classmethod
    def from_split(cls, split) -> "MotionDataset":
        return cls(network_image(split.rgb, split.depth), np.asarray(split.motions, np.float32))

    def __len__(self) -> int:
        return len(self.motions)

    def batch(self, seed: int, step: int, size: int, process: int = 0, near: int = 0) -> dict[str, np.ndarray]:
        """The batch of ``step``: a pure function of (seed, step, process), so a resumed run
        sees exactly the batches an uninterrupted one would. Sampled without replacement
        within the batch (an image's negatives are the *other* images' motions). ``near`` > 0
        adds ``near [size, near, 101, 11]``: each motion's ``near`` nearest other motions."""
        if size > len(self):
            raise ValueError(f"batch size {size} exceeds the dataset's {len(self)} episodes")
        rng = np.random.default_rng([seed, step, process])
        idx = np.sort(rng.choice(len(self), size, replace=False))
        batch = {"images": self.images[idx], "motions": self.motions[idx]}
        if near:
            if self.neighbours is None or self.neighbours.shape[1] < near:
                have = 0 if self.neighbours is None else self.neighbours.shape[1]
                raise ValueError(f"batches with {near} nearest motions need the dataset's neighbours "
                                 f"(dmo_jax.neighbours), {have} per motion here")
            batch["near"] = self.motions[self.neighbours[idx, :near]]
        return batch

    def statistics(self) -> dict:
        """Summary saved beside checkpoints (what the model was trained on)."""
        m = self.motions
        return {
            "fingerprint": motions_fingerprint(m),
            "episodes": len(self),
            "image_size": int(self.images.shape[1]),
            "motion_mean": m.mean(axis=(0, 1)).round(5).tolist(),
            "motion_std": m.std(axis=(0, 1)).round(5).tolist(),
        }
