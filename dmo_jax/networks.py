"""EBM and DMO networks (docs/method.md, "Networks"; paper Sec. III-C and Table 2).

Both networks = ConvNeXt U-Net encoder (``dmo_jax.encoder``) + a motion head. The encoder
runs once per image; the head takes ``(F [H, W, C], motions [..., 101, 11])`` for any
number of candidates and can be ``jax.vmap``-ed over candidates and over images.

Head of variant ``concat`` (the paper's model), per motion:

* pose MLP on each pose p_t: 11 -> w -> 2w -> 2w -> w (GELU + dropout between) -> g_t;
* spatially-aligned temporal encoding: f_t = bilinear sample of F at uv_t
  (:func:`bilinear_sample`); c_t = [f_t, g_t] -> MLP 2w -> 2w -> 2w -> w (GELU after each);
  (option ``depth_cue``, not in the paper: F carries the image's depth as a last channel and
  the MLP also reads, per pose, the image's depth at uv_t minus the pose's depth, in dm,
  or tanh of it over ``depth_cue_range`` metres; ``wo_concat`` adds a projection of it to the
  pose's sampled image token);
* Transformer over the 101 tokens (:class:`TransformerBlock`, as the reference: no LayerNorm);
* EBM: mean over tokens -> MLP w -> w -> w -> w/2 -> w/2 -> 1 = energy (lower is better);
* DMO: per token w -> w -> w -> w/2 -> w/2 (GELU), then one head per key
  (Dense w/2 -> PReLU -> Dense d -> PReLU, as the reference) giving a residual added to
  the input pose; grasp clamped to [0, 1]; time passed through.

Other variants (tokens into the Transformer): ``wo_concat`` 101 sampled image tokens +
101 pose tokens; ``gap`` the global average of F + 101 pose tokens; ``vit`` a
(H/16)x(W/16)-stride patch conv on F giving 16 x 16 = 256 tokens + sinusoidal positions,
+ 101 pose tokens. The EBM averages all tokens; the DMO reads the 101 pose tokens.

Pure API: :class:`EBMNet` / :class:`DMONet` hold only the configuration; parameters go in
and arrays come out (``init``, ``encode``, ``energy`` / ``refine``). ``EBMNet.pose_activations``
is the head's work on the poses alone (the pose MLP, and for ``concat`` the pose rows of the
first mix layer), which does not depend on the image; ``energy(..., pose=...)`` takes it back,
so a bank's is computed once (``dmo_jax.inference.cache_bank``).
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from envs.motion import NUM_STEPS, POSE_DIM, POSE_KEYS

from .config import HeadConfig, Preset, get_preset
from .data import DEPTH_FAR, DEPTH_NEAR
from .encoder import ConvNeXtUNet, PatchConv, gelu

Params = Any


# --------------------------------------------------------------------------- sampling
def bilinear_sample(feature: jnp.ndarray, uv: jnp.ndarray) -> jnp.ndarray:
    """Bilinear sample of ``feature [H, W, C]`` at normalised points ``uv [..., 2]`` -> ``[..., C]``.

    ``uv[..., 0]`` is horizontal (u, width), ``uv[..., 1]`` vertical (v, height), both in
    [-1, 1] with the align-corners convention: -1 / +1 are the centres of the first / last
    pixel, pixel ``x = (u + 1) / 2 * (W - 1)``. Taps outside the image count as zeros
    (torch ``grid_sample(..., padding_mode="zeros", align_corners=True)``). Differentiable
    in ``feature`` and (piecewise) in ``uv``.
    """
    h, w, _ = feature.shape
    x = (uv[..., 0] + 1.0) * 0.5 * (w - 1)
    y = (uv[..., 1] + 1.0) * 0.5 * (h - 1)
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx, fy = x - x0, y - y0
    x0 = x0.astype(jnp.int32)
    y0 = y0.astype(jnp.int32)
    out = 0.0
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            tap = feature[jnp.clip(yi, 0, h - 1), jnp.clip(xi, 0, w - 1)]
            out = out + tap * jnp.where(inside, wx * wy, 0.0)[..., None]
    return out


def sinusoidal_positions(length: int, dim: int) -> np.ndarray:
    """``[length, dim]`` Transformer positional encoding (sin on even, cos on odd channels)."""
    pos = np.arange(length, dtype=np.float64)[:, None]
    div = np.exp(np.arange(0, dim, 2, dtype=np.float64) * (-np.log(10000.0) / dim))
    pe = np.zeros((length, dim))
    pe[:, 0::2] = np.sin(pos * div)
    pe[:, 1::2] = np.cos(pos * div)
    return pe.astype(np.float32)


# --------------------------------------------------------------------------- layers
class MLP(nn.Module):
    """Dense layers ``features``; GELU after each (and after the last iff ``final_act``)."""

    features: tuple[int, ...]
    final_act: bool = True
    dropout: float = 0.0

    @nn.compact
    def __call__(self, x, deterministic: bool = True):
        for i, f in enumerate(self.features):
            x = nn.Dense(f)(x)
            if i < len(self.features) - 1 or self.final_act:
                x = gelu(x)
                if self.dropout > 0.0 and i < len(self.features) - 1:
                    x = nn.Dropout(self.dropout)(x, deterministic=deterministic)
        return x


class MultiHeadAttention(nn.Module):
    """torch.nn.MultiheadAttention: separate q/k/v input projections, scaled dot product, output projection.

    q ``[..., Sq, D]``, kv ``[..., Sk, D]`` (kv = k = v input) -> ``[..., Sq, D]``.
    """

    num_heads: int
    dropout: float = 0.0

    @nn.compact
    def __call__(self, q, k, v, deterministic: bool = True):
        d = q.shape[-1]
        hd = d // self.num_heads

        def heads(x, name):
            return nn.Dense(d, name=name)(x).reshape(x.shape[:-1] + (self.num_heads, hd))

        # Heads moved ahead of the tokens before the two batched products: XLA:CPU runs
        # [..., h, T, d] @ [..., h, d, T] 3x faster than the equivalent einsum over
        # [..., T, h, d] (measured at 1000 x 101 tokens, 4 heads of 16: 0.30 s vs 0.93 s).
        qh, kh, vh = (jnp.swapaxes(heads(x, name), -2, -3)
                      for x, name in ((q, "q_proj"), (k, "k_proj"), (v, "v_proj")))
        logits = jnp.matmul(qh, jnp.swapaxes(kh, -1, -2)) / np.sqrt(hd)
        weights = jax.nn.softmax(logits, axis=-1)
        if self.dropout > 0.0:
            weights = nn.Dropout(self.dropout)(weights, deterministic=deterministic)
        out = jnp.swapaxes(jnp.matmul(weights, vh), -2, -3).reshape(q.shape)
        return nn.Dense(d, name="out_proj")(out)


class TransformerBlock(nn.Module):
    """The reference block: ``x += MHA(split(GELU(Dense 3w)))``; ``x += FF(x)``, FF = 3 x (Dense w + GELU).

    No LayerNorm and no positional encoding.
    """

    num_heads: int

    @nn.compact
    def __call__(self, x, deterministic: bool = True):
        w = x.shape[-1]
        qkv = gelu(nn.Dense(3 * w, name="qkv")(x))
        q, k, v = jnp.split(qkv, 3, axis=-1)
        x = x + MultiHeadAttention(self.num_heads, name="attn")(q, k, v, deterministic)
        return x + MLP((w, w, w), final_act=True, name="ff")(x)


# --------------------------------------------------------------------------- heads
class _SplitDense(nn.Module):
    """``nn.Dense(features)`` on the concatenation of parts of ``widths`` (the same parameters),
    which can also take one part's product with its rows of the kernel computed beforehand."""

    features: int
    widths: tuple[int, ...]

    def setup(self):
        self.kernel = self.param("kernel", nn.initializers.lecun_normal(), (sum(self.widths), self.features))
        self.bias = self.param("bias", nn.initializers.zeros_init(), (self.features,))

    def rows(self, i: int):
        start = sum(self.widths[:i])
        return self.kernel[start:start + self.widths[i]]

    def __call__(self, parts, known: int | None = None, product=None):
        """``parts``: arrays ``[..., widths[i]]``; with ``known`` = i, ``product`` = ``parts[i] @ rows(i)``
        replaces that part (equal to float rounding)."""
        if known is None:
            x = jnp.concatenate(parts, -1)
            return jax.lax.dot_general(x, self.kernel, (((x.ndim - 1,), (0,)), ((), ()))) + self.bias
        out = product + self.bias
        for i, x in enumerate(parts):
            if i != known:
                out = out + x @ self.rows(i)
        return out


class MixMLP(nn.Module):
    """The concat variant's feature mix: ``[f_t, g_t(, cue_t)]`` -> 2w -> 2w -> w, GELU after each.
    The pose part of its first layer, ``g_t W_g``, does not depend on the image: :meth:`pose_part`
    computes it, once per bank (:meth:`EBM.pose_activations`), and ``__call__`` takes it instead of
    ``g_t``."""

    width: int
    depth_cue: bool

    def setup(self):
        w = self.width
        # Named as nn.Dense layers of an MLP are, so the parameters keep their layout.
        self.Dense_0 = _SplitDense(2 * w, (w, w) + ((1,) if self.depth_cue else ()))
        self.Dense_1 = nn.Dense(2 * w)
        self.Dense_2 = nn.Dense(w)

    def pose_part(self, g):
        """``g [..., T, w] -> g W_g [..., T, 2w]``."""
        return g @ self.Dense_0.rows(1)

    def __call__(self, f, g, cue=None, pose_part=None):
        """``f [..., T, w]`` sampled features, ``g [..., T, w]`` pose tokens (or None with ``pose_part``),
        ``cue [..., T, 1]`` (with ``depth_cue``) -> tokens ``[..., T, w]``."""
        parts = [f, g] + ([cue] if self.depth_cue else [])
        x = self.Dense_0(parts) if pose_part is None else self.Dense_0(parts, known=1, product=pose_part)
        return gelu(self.Dense_2(gelu(self.Dense_1(gelu(x)))))


class MotionTrunk(nn.Module):
    """Tokens -> Transformer features, per variant.

    ``feature [H, W, w]``, ``motions [n, T, 11]`` -> ``(all_tokens [n, S, w], pose_tokens [n, T, w])``.
    ``pose``: the motions' image-independent activations from a call with ``feature=None``, which
    returns them alone (``concat``: ``g_t W_g [n, T, 2w]``, the pose part of the first mix layer;
    the other variants: the pose tokens ``g_t [n, T, w]``); None: computed here.
    """

    config: HeadConfig

    @nn.compact
    def __call__(self, feature, motions, deterministic: bool = True, pose=None):
        cfg = self.config
        w = cfg.width
        n = motions.shape[0]
        concat = cfg.variant == "concat"
        mix = MixMLP(w, cfg.depth_cue, name="mix_mlp") if concat else None
        g = None
        if pose is None:
            g = MLP((w, 2 * w, 2 * w, w), final_act=False, dropout=cfg.dropout, name="pose_mlp")(motions, deterministic)
        if feature is None:
            return mix.pose_part(g) if concat else g
        if concat:
            f, cue = _sample_along(feature, motions, cfg)
            tokens = mix(f, g, cue, pose_part=pose)
            image_tokens = 0
        else:
            g = g if pose is None else pose
            if cfg.variant == "wo_concat":
                image, cue = _sample_along(feature, motions, cfg)
                if cfg.depth_cue:
                    image = image + nn.Dense(w, use_bias=False, name="depth_cue")(cue)
            elif cfg.variant == "gap":
                image = jnp.broadcast_to(jnp.mean(feature, axis=(0, 1)), (n, 1, w))
            elif cfg.variant == "vit":
                h = feature.shape[0] // cfg.vit_tokens_per_side
                p = PatchConv(w, h, name="patch")(feature[None])[0].reshape(-1, w)
                image = jnp.broadcast_to(p + sinusoidal_positions(p.shape[0], w), (n,) + p.shape)
            else:  # HeadConfig validates the name; this guards future additions
                raise ValueError(f"unhandled variant {cfg.variant!r}")
            tokens, image_tokens = jnp.concatenate([image, g], axis=-2), image.shape[-2]
        for i in range(cfg.num_blocks):
            tokens = TransformerBlock(cfg.num_heads, name=f"block{i}")(tokens, deterministic)
        return tokens, tokens[:, image_tokens:]


def _sample_along(feature, motions, cfg: HeadConfig):
    """F sampled at each pose's pixel: ``(f [n, T, w], cue [n, T, 1] or None)``, the cue (with
    ``depth_cue``, F's last channel being the image's depth; see ``_ImageMotionModule.encode``)
    the image's depth there minus the pose's depth, in decimetres or squashed by ``depth_cue_range``."""
    f = bilinear_sample(feature, motions[..., POSE_KEYS["uv"]])
    if not cfg.depth_cue:
        return f, None
    w = cfg.width
    f, image_depth = f[..., :w], DEPTH_NEAR + f[..., w:] * (DEPTH_FAR - DEPTH_NEAR)
    gap = image_depth - motions[..., POSE_KEYS["z"]]
    return f, jnp.tanh(gap / cfg.depth_cue_range) if cfg.depth_cue_range else gap * 10.0


def _flatten_motions(motions, any_length: bool = False):
    """``[..., T, 11] -> ([M, T, 11], leading shape)``; T must be 101 unless ``any_length``."""
    steps_ok = motions.ndim >= 2 and (motions.shape[-2] > 0 if any_length else motions.shape[-2] == NUM_STEPS)
    if not steps_ok or motions.shape[-1] != POSE_DIM:
        raise ValueError(f"motions must be [..., {'T' if any_length else NUM_STEPS}, {POSE_DIM}], got {motions.shape}")
    return motions.reshape((-1,) + motions.shape[-2:]), motions.shape[:-2]


def _check_feature(feature, head: HeadConfig):
    width = head.feature_channels
    if feature.ndim != 3 or feature.shape[-1] != width:
        raise ValueError(
            f"feature must be one image's F [H, W, {width}] (vmap over images), got {feature.shape}"
        )


class _ImageMotionModule(nn.Module):
    """What the EBM and the DMO share: the image encoder (F, computed once per image) and the
    motion trunk that reads F along each motion."""

    preset: Preset

    def setup(self):
        self.encoder = ConvNeXtUNet(self.preset.encoder)
        self.trunk = MotionTrunk(self.preset.head)

    def encode(self, image, deterministic: bool = True):
        """``image [..., H, W, 4] -> F [..., H, W, w]`` (``w + 1`` channels with ``depth_cue``)."""
        feature = self.encoder(image, deterministic)
        if self.preset.head.depth_cue:  # the network image's depth channel, read again by the head at each pose
            feature = jnp.concatenate([feature, image[..., 3:4].astype(feature.dtype)], axis=-1)
        return feature


class EBM(_ImageMotionModule):
    """Energy-based model E(I, P); lower energy = better motion."""

    def setup(self):
        super().setup()
        w = self.preset.head.width
        self.energy_mlp = MLP((w, w, w // 2, w // 2, 1), final_act=False)

    def energy(self, feature, motions, pose=None, deterministic: bool = True):
        """``F [H, W, w]``, ``motions [..., T, 11]`` -> energies ``[...]``. T is 101 but for a
        coarse ranking (``inference``), which scores motions on a subset of their poses.
        ``pose``: the motions' :meth:`pose_activations` ``[..., T, P]``, computed beforehand."""
        return self.energy_of_pooled(self.pooled(feature, motions, pose, deterministic))

    def energy_of_pooled(self, pooled, deterministic: bool = True):
        """:meth:`pooled` tokens ``[..., w]`` -> energies ``[...]``."""
        return self.energy_mlp(pooled)[..., 0]

    def pooled(self, feature, motions, pose=None, deterministic: bool = True):
        """The head's tokens averaged over each motion, what the energy is read from:
        ``F [H, W, w]``, ``motions [..., T, 11]`` -> ``[..., w]``."""
        return self.pooled_and_phases(feature, motions, 0, pose, deterministic)[0]

    def pooled_and_phases(self, feature, motions, phases: int, pose=None, deterministic: bool = True):
        """:meth:`pooled` and, from the same pass, the pose tokens averaged over each of ``phases``
        consecutive, nearly equal parts of the motion, ``[..., phases, w]`` (None for 0)."""
        _check_feature(feature, self.preset.head)
        flat, lead = _flatten_motions(motions, any_length=True)
        if pose is not None:
            pose = pose.reshape(flat.shape[:2] + pose.shape[-1:])
        tokens, pose_tokens = self.trunk(feature, flat, deterministic, pose)
        pooled = jnp.mean(tokens, axis=-2).reshape(lead + tokens.shape[-1:])
        if not phases:
            return pooled, None
        parts = jnp.stack([jnp.mean(p, axis=-2) for p in jnp.array_split(pose_tokens, phases, axis=-2)], axis=-2)
        return pooled, parts.reshape(lead + parts.shape[-2:])

    def pose_activations(self, motions, deterministic: bool = True):
        """``motions [..., T, 11]`` -> the head's activations that do not depend on the image,
        ``[..., T, P]`` (P = 2w for ``concat``, w else; see :class:`MotionTrunk`)."""
        flat, lead = _flatten_motions(motions, any_length=True)
        pose = self.trunk(None, flat, deterministic)
        return pose.reshape(lead + pose.shape[1:])

    def __call__(self, image, motions, deterministic: bool = True):
        return self.energy(self.encode(image, deterministic), motions, deterministic=deterministic)


class DMOHead(nn.Module):
    """Per-token features ``[..., 101, w]`` + input motions -> refined motions ``[..., 101, 11]``."""

    width: int

    @nn.compact
    def __call__(self, tokens, motions):
        w = self.width
        h = MLP((w, w, w // 2, w // 2), final_act=True, name="shared_mlp")(tokens)
        parts = []
        for key, sl in POSE_KEYS.items():
            x = motions[..., sl]
            if key != "time":
                d = sl.stop - sl.start
                r = nn.PReLU(negative_slope_init=0.25, name=f"{key}_act0")(nn.Dense(w // 2, name=f"{key}_fc0")(h))
                r = nn.PReLU(negative_slope_init=0.25, name=f"{key}_act1")(nn.Dense(d, name=f"{key}_fc1")(r))
                x = x + r
                if key == "grasp":
                    x = jnp.clip(x, 0.0, 1.0)
            parts.append(x)
        return jnp.concatenate(parts, axis=-1)


class DMO(_ImageMotionModule):
    """Deep Motion Optimizer: one residual refinement step of candidate motions."""

    def setup(self):
        super().setup()
        self.head = DMOHead(self.preset.head.width)

    def refine(self, feature, motions, deterministic: bool = True):
        """``F [H, W, w]``, ``motions [..., 101, 11]`` -> refined motions, same shape."""
        _check_feature(feature, self.preset.head)
        flat, lead = _flatten_motions(motions)
        _, pose_tokens = self.trunk(feature, flat, deterministic)
        return self.head(pose_tokens, flat).reshape(motions.shape)

    def __call__(self, image, motions, deterministic: bool = True):
        return self.refine(self.encode(image, deterministic), motions, deterministic)


# --------------------------------------------------------------------------- pure API
def _rngs(train: bool, rng):
    if not train:
        return {}
    if rng is None:
        raise ValueError("train=True needs rng (dropout / drop path)")
    return {"dropout": rng}


class PureNet:
    """A Flax module behind pure functions, parameters in and arrays out: ``init(rng)``,
    ``param_shapes()`` and the module's methods through :meth:`_apply`. Subclasses give the
    ``module`` and the example inputs ``init`` traces it with."""

    @property
    def module(self) -> nn.Module:
        raise NotImplementedError

    def _example_inputs(self) -> tuple:
        """The module's inputs for ``init``, as ``jax.ShapeDtypeStruct``."""
        raise NotImplementedError

    def init(self, rng) -> Params:
        """Parameters ``{"params": ...}``. Flax's ``lazy_init`` traces the module on the abstract
        example inputs and runs only the initialisers, not the forward pass: the same values as
        ``module.init`` on real inputs, bit for bit, in about 20 % less time (the cpu preset's EBM
        on 2 cores: 17 against 21 s, most of it compiling the initialisers' small programs)."""
        return self.module.lazy_init({"params": rng}, *self._example_inputs())

    def param_shapes(self) -> Params:
        """Like :meth:`init` but only shapes (``jax.eval_shape``), nothing computed. Traced once
        per network (about 0.5 s for the tiny preset's EBM: Flax runs the whole forward pass)."""
        return jax.tree.map(lambda x: x, _param_shapes(self))  # a fresh tree: callers may edit it

    def _apply(self, params, method: str, *args, train: bool, rng):
        return self.module.apply(params, *args, not train, method=method, rngs=_rngs(train, rng))


@functools.cache
def _param_shapes(net: PureNet) -> Params:
    return jax.eval_shape(net.init, jax.random.key(0))


@dataclasses.dataclass(frozen=True)
class _Net(PureNet):
    preset: Preset

    @classmethod
    def from_name(cls, preset: str = "cpu", variant: str | None = None):
        return cls(get_preset(preset, variant))

    def _example_inputs(self) -> tuple:
        s = self.preset.image_size  # one image and one motion
        return jax.ShapeDtypeStruct((s, s, 4), jnp.float32), jax.ShapeDtypeStruct((1, NUM_STEPS, POSE_DIM), jnp.float32)

    def encode(self, params, image, *, train: bool = False, rng=None):
        """``image [..., H, W, 4] float32`` (RGB in [0, 1] + depth) -> ``F [..., H, W, w] float32``."""
        return self._apply(params, "encode", image, train=train, rng=rng)


class EBMNet(_Net):
    """Pure EBM: ``encode(params, image) -> F``; ``energy(params, F, motions) -> [...]``."""

    @property
    def module(self) -> EBM:
        return EBM(self.preset)

    def energy(self, params, feature, motions, *, pose=None, train: bool = False, rng=None):
        """``F [H, W, w]``, ``motions [..., 101, 11]`` -> energies ``[...]`` (lower is better);
        ``pose``: the motions' :meth:`pose_activations` (equal energies to float rounding)."""
        return self._apply(params, "energy", feature, motions, pose, train=train, rng=rng)

    def pooled_and_phases(self, params, feature, motions, phases: int):
        """``F [H, W, w]``, ``motions [..., 101, 11]`` -> the head's tokens averaged over each motion
        ``[..., w]`` (the energy is an MLP of them) and its pose tokens averaged over each of
        ``phases`` consecutive parts of the motion ``[..., phases, w]``, from one pass."""
        return self._apply(params, "pooled_and_phases", feature, motions, phases, None, train=False, rng=None)

    def energy_of_pooled(self, params, pooled):
        """The tokens averaged over each motion ``[..., w]`` (:meth:`pooled_and_phases`) -> their
        energies ``[...]``, equal to :meth:`energy`'s."""
        return self._apply(params, "energy_of_pooled", pooled, train=False, rng=None)

    def pose_activations(self, params, motions):
        """``motions [..., T, 11]`` -> ``[..., T, P]``: the head's work on the poses alone, which
        does not depend on the image; a bank's, computed once, serves every image."""
        return self._apply(params, "pose_activations", motions, train=False, rng=None)


class DMONet(_Net):
    """Pure DMO: ``encode(params, image) -> F``; ``refine(params, F, motions) -> motions`` (one step)."""

    @property
    def module(self) -> DMO:
        return DMO(self.preset)

    def refine(self, params, feature, motions, *, train: bool = False, rng=None):
        """``F [H, W, w]``, ``motions [..., 101, 11]`` -> refined motions (same shape)."""
        return self._apply(params, "refine", feature, motions, train=train, rng=rng)


def count_params(params: Params) -> int:
    """Number of scalars in a parameter tree (arrays or ShapeDtypeStructs)."""
    return int(sum(np.prod(x.shape) for x in jax.tree.leaves(params)))
