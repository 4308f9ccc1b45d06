"""ConvNeXt U-Net image encoder (docs/method.md, "Networks").

``image [..., H, W, 4] float32 -> F [..., H, W, C]`` with ``C = EncoderConfig.out_dim``
(128 in the paper preset). Layout is NHWC throughout.

Architecture (widths ``d = dims``, ``L = len(dims)``):

* stem: 3x3 conv 4 -> d0 + exact GELU at full resolution;
* down 0: 4x4/4 conv d0 -> d0 + GroupNorm(1, d0); down i > 0: GroupNorm(1, d_{i-1}) + 2x2/2 conv;
  stage i: ``enc_depths[i]`` ConvNeXt blocks at width d_i (drop path rising 0 -> rate);
* decoder level i = L-2 .. 0: GroupNorm(1, d_{i+1}) + 2x2/2 transposed conv d_{i+1} -> d_i,
  concat [upsampled, skip_i], 1x1 conv 2 d_i -> d_i, ``dec_depths[i]`` ConvNeXt blocks
  (drop path falling rate -> 0 over the decoder block index);
* head: 4x4/4 transposed conv d0 -> out_dim, so F has the input's spatial size.

Speed notes (see BENCHMARKS.md). The computation is the textbook one, but three ops
are written so that XLA:CPU runs them well:

* every conv whose kernel equals its stride (4x4/4, 2x2/2, and the transposed ones) is
  a space-to-depth / depth-to-space reshape around one matrix product. For the
  transposed convs this avoids XLA's lhs-dilated convolution, which multiplies the
  inserted zeros and costs ``stride**2`` times the real work;
* the depthwise 7x7 conv is, by default, a sum of 49 shifted multiply-adds that XLA
  fuses into one loop vectorised over channels (``dwconv_impl="shift"``); the plain
  grouped convolution is kept as ``dwconv_impl="conv"``;
* GroupNorm(1, C) and LayerNorm compute mean and variance in float32 in one pass.

``compute_dtype=bfloat16`` runs the matrix products and convolutions in bf16 (params and
normalisation statistics stay float32); its accuracy effect is measured in
``dmo_jax.benchmarks.encoder``.
"""
from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from .config import EncoderConfig

Dtype = Any

conv_init = nn.initializers.truncated_normal(stddev=0.02)
zeros = nn.initializers.zeros


def gelu(x: jnp.ndarray) -> jnp.ndarray:
    """Exact (erf) GELU, as torch.nn.GELU()."""
    return jax.nn.gelu(x, approximate=False)


# --------------------------------------------------------------------------- primitives
class Dense(nn.Module):
    """``[..., in] -> [..., features]`` matrix product in ``dtype`` (params float32)."""

    features: int
    dtype: Dtype = jnp.float32
    kernel_init: Any = conv_init

    @nn.compact
    def __call__(self, x):
        k = self.param("kernel", self.kernel_init, (x.shape[-1], self.features))
        b = self.param("bias", zeros, (self.features,))
        y = jnp.dot(x.astype(self.dtype), k.astype(self.dtype), preferred_element_type=jnp.float32)
        return y + b


class PatchConv(nn.Module):
    """Conv with kernel = stride = ``patch`` and no padding, on ``[B, H, W, C]``.

    Kernel ``[p, p, C, C_out]`` (HWIO, as a conv). Computed as space-to-depth + one matmul.
    """

    features: int
    patch: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x):
        p = self.patch
        b, h, w, c = x.shape
        if h % p or w % p:
            raise ValueError(f"PatchConv: spatial size {(h, w)} not divisible by {p}")
        k = self.param("kernel", conv_init, (p, p, c, self.features))
        bias = self.param("bias", zeros, (self.features,))
        x = x.reshape(b, h // p, p, w // p, p, c).transpose(0, 1, 3, 2, 4, 5)
        x = x.reshape(b, h // p, w // p, p * p * c)
        y = jnp.dot(
            x.astype(self.dtype),
            k.reshape(p * p * c, self.features).astype(self.dtype),
            preferred_element_type=jnp.float32,
        )
        return y + bias


class PatchConvTranspose(nn.Module):
    """Transposed conv with kernel = stride = ``patch`` on ``[B, h, w, C]`` -> ``[B, h p, w p, C_out]``.

    Output pixel ``(i p + a, j p + b) = sum_c x[i, j, c] kernel[a, b, c, :] + bias``
    (the inputs' footprints do not overlap). Computed as one matmul + depth-to-space.
    """

    features: int
    patch: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x):
        p = self.patch
        b, h, w, c = x.shape
        k = self.param("kernel", conv_init, (p, p, c, self.features))
        bias = self.param("bias", zeros, (self.features,))
        km = k.transpose(2, 0, 1, 3).reshape(c, p * p * self.features)
        y = jnp.dot(x.astype(self.dtype), km.astype(self.dtype), preferred_element_type=jnp.float32)
        y = y.reshape(b, h, w, p, p, self.features).transpose(0, 1, 3, 2, 4, 5)
        return y.reshape(b, h * p, w * p, self.features) + bias


class Conv3x3(nn.Module):
    """3x3 conv, stride 1, zero 'SAME' padding, on ``[B, H, W, C]`` (kernel HWIO)."""

    features: int
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x):
        k = self.param("kernel", conv_init, (3, 3, x.shape[-1], self.features))
        bias = self.param("bias", zeros, (self.features,))
        y = jax.lax.conv_general_dilated(
            x.astype(self.dtype), k.astype(self.dtype), (1, 1), "SAME",
            dimension_numbers=("NHWC", "HWIO", "NHWC"), preferred_element_type=jnp.float32,
        )
        return y + bias


def depthwise_conv_shift(x: jnp.ndarray, kernel: jnp.ndarray) -> jnp.ndarray:
    """Depthwise conv, zero 'SAME' padding, as a sum of shifted products.

    x ``[B, H, W, C]``, kernel ``[k, k, C]`` -> ``[B, H, W, C]`` (accumulated in float32).
    """
    k = kernel.shape[0]
    r = k // 2
    _, h, w, _ = x.shape
    xp = jnp.pad(x, ((0, 0), (r, r), (r, r), (0, 0)))
    out = None
    for i in range(k):
        for j in range(k):
            term = xp[:, i : i + h, j : j + w, :].astype(jnp.float32) * kernel[i, j].astype(jnp.float32)
            out = term if out is None else out + term
    return out


def depthwise_conv_lax(x: jnp.ndarray, kernel: jnp.ndarray) -> jnp.ndarray:
    """Same as :func:`depthwise_conv_shift`, as a grouped XLA convolution."""
    c = x.shape[-1]
    return jax.lax.conv_general_dilated(
        x, kernel[:, :, None, :].astype(x.dtype), (1, 1), "SAME",
        dimension_numbers=("NHWC", "HWIO", "NHWC"), feature_group_count=c,
        preferred_element_type=jnp.float32,
    )


class DepthwiseConv(nn.Module):
    """Depthwise ``k x k`` conv with bias; ``impl`` is "shift" or "conv" (same result)."""

    kernel_size: int = 7
    impl: str = "shift"
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x):
        c = x.shape[-1]
        k = self.param("kernel", conv_init, (self.kernel_size, self.kernel_size, c))
        bias = self.param("bias", zeros, (c,))
        if self.impl == "shift":
            y = depthwise_conv_shift(x.astype(self.dtype), k.astype(self.dtype))
        elif self.impl == "conv":
            y = depthwise_conv_lax(x.astype(self.dtype), k)
        else:
            raise ValueError(f"unknown dwconv_impl {self.impl!r}; valid: 'shift', 'conv'")
        return y + bias


class ChannelNorm(nn.Module):
    """Normalise over the last ``axes`` (float32 statistics) with a per-channel affine.

    ``axes=1`` is LayerNorm over channels; ``axes=3`` on NHWC is GroupNorm(1, C).
    """

    axes: int = 1
    eps: float = 1e-6

    @nn.compact
    def __call__(self, x):
        c = x.shape[-1]
        scale = self.param("scale", nn.initializers.ones, (c,))
        bias = self.param("bias", zeros, (c,))
        x = x.astype(jnp.float32)
        red = tuple(range(x.ndim - self.axes, x.ndim))
        mean = jnp.mean(x, axis=red, keepdims=True)
        var = jnp.mean(jnp.square(x), axis=red, keepdims=True) - jnp.square(mean)
        inv = jax.lax.rsqrt(jnp.maximum(var, 0.0) + self.eps)
        return (x - mean) * inv * scale + bias


def drop_path(x: jnp.ndarray, rate: float, deterministic: bool, rng) -> jnp.ndarray:
    """Stochastic depth on a residual branch ``x [B, ...]``: drop whole samples."""
    if deterministic or rate == 0.0:
        return x
    keep = 1.0 - rate
    mask = jax.random.bernoulli(rng, keep, (x.shape[0],) + (1,) * (x.ndim - 1))
    return jnp.where(mask, x / keep, 0.0)


# --------------------------------------------------------------------------- blocks
class ConvNeXtBlock(nn.Module):
    """dw 7x7 -> LayerNorm(1e-6) -> Dense 4C -> GELU -> Dense C -> layer scale -> drop path -> + x."""

    drop_path: float = 0.0
    layer_scale_init: float = 1e-6
    dwconv_impl: str = "shift"
    dtype: Dtype = jnp.float32

    @nn.compact
    def __call__(self, x, deterministic: bool = True):
        c = x.shape[-1]
        y = DepthwiseConv(7, self.dwconv_impl, self.dtype, name="dwconv")(x)
        y = ChannelNorm(axes=1, eps=1e-6, name="norm")(y)
        y = gelu(Dense(4 * c, self.dtype, name="pwconv1")(y))
        y = Dense(c, self.dtype, name="pwconv2")(y)
        gamma = self.param("gamma", nn.initializers.constant(self.layer_scale_init), (c,))
        y = y * gamma
        rng = None if deterministic or self.drop_path == 0.0 else self.make_rng("dropout")
        return x + drop_path(y, self.drop_path, deterministic, rng)


class ConvNeXtUNet(nn.Module):
    """``image [..., H, W, in] -> F [..., H, W, out_dim]`` (float32). H, W divisible by 4 * 2**(L-1)."""

    config: EncoderConfig

    @nn.compact
    def __call__(self, image, deterministic: bool = True):
        cfg = self.config
        dt = jnp.dtype(cfg.compute_dtype)
        dims, L = cfg.dims, len(cfg.dims)
        lead = image.shape[:-3]
        x = image.reshape((-1,) + image.shape[-3:]).astype(jnp.float32)
        factor = 4 * 2 ** (L - 1)
        if x.shape[1] % factor or x.shape[2] % factor:
            raise ValueError(f"image size {x.shape[1:3]} must be divisible by {factor}")

        def block(y, rate, name):
            return ConvNeXtBlock(rate, cfg.layer_scale_init, cfg.dwconv_impl, dt, name=name)(
                y, deterministic
            )

        enc_rates = np.linspace(0.0, cfg.drop_path_rate, sum(cfg.enc_depths))
        dec_rates = np.linspace(cfg.drop_path_rate, 0.0, sum(cfg.dec_depths))

        x = gelu(Conv3x3(dims[0], dt, name="stem")(x))
        skips = []
        cur = 0
        for i in range(L):
            if i == 0:
                x = PatchConv(dims[0], 4, dt, name="down0_conv")(x)
                x = ChannelNorm(3, 1e-5, name="down0_norm")(x)
            else:
                x = ChannelNorm(3, 1e-5, name=f"down{i}_norm")(x)
                x = PatchConv(dims[i], 2, dt, name=f"down{i}_conv")(x)
            for j in range(cfg.enc_depths[i]):
                x = block(x, float(enc_rates[cur + j]), f"enc{i}_block{j}")
            cur += cfg.enc_depths[i]
            skips.append(x)

        offsets = np.cumsum([0] + list(cfg.dec_depths))
        for i in reversed(range(L - 1)):
            x = ChannelNorm(3, 1e-5, name=f"up{i}_norm")(x)
            x = PatchConvTranspose(dims[i], 2, dt, name=f"up{i}_conv")(x)
            x = jnp.concatenate([x, skips[i]], axis=-1)
            x = Dense(dims[i], dt, name=f"dec{i}_fuse")(x)
            for j in range(cfg.dec_depths[i]):
                x = block(x, float(dec_rates[offsets[i] + j]), f"dec{i}_block{j}")
        x = PatchConvTranspose(cfg.out_dim, 4, dt, name="head")(x)
        return x.reshape(lead + x.shape[1:])
