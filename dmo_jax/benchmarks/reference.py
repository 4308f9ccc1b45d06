"""Plain reference implementations of what the library computes a faster way: the encoder
with textbook XLA convolutions, and ``predict()`` without reusing F. The benchmarks time the
library against them; the tests check that both compute the same function."""
from __future__ import annotations

import jax
import jax.numpy as jnp

from dmo_jax.config import EncoderConfig
from dmo_jax.encoder import gelu


def plain_encoder_forward(params, image: jnp.ndarray, cfg: EncoderConfig) -> jnp.ndarray:
    """The encoder of :class:`ConvNeXtUNet` written with plain XLA convolutions.

    Same parameters (``ConvNeXtUNet.init`` tree, without the ``"params"`` level) and
    same function; ``image [B, H, W, 4] -> F [B, H, W, out_dim]``. Float32, inference.
    """
    dn = ("NHWC", "HWIO", "NHWC")

    def conv(x, p, stride, padding, groups=1):
        k = p["kernel"] if p["kernel"].ndim == 4 else p["kernel"][:, :, None, :]
        y = jax.lax.conv_general_dilated(x, k, (stride, stride), padding, dimension_numbers=dn,
                                         feature_group_count=groups)
        return y + p["bias"]

    def conv_t(x, p, stride):
        # out[i s + a] = x[i] K[a]: a transposed conv with the spatially flipped kernel.
        k = p["kernel"][::-1, ::-1]
        return jax.lax.conv_transpose(x, k, (stride, stride), "VALID", dimension_numbers=dn) + p["bias"]

    def norm(x, p, axes, eps):
        mean = jnp.mean(x, axis=axes, keepdims=True)
        var = jnp.mean(jnp.square(x - mean), axis=axes, keepdims=True)
        return (x - mean) / jnp.sqrt(var + eps) * p["scale"] + p["bias"]

    def block(x, p):
        y = conv(x, p["dwconv"], 1, "SAME", groups=x.shape[-1])
        y = norm(y, p["norm"], (-1,), 1e-6)
        y = gelu(y @ p["pwconv1"]["kernel"] + p["pwconv1"]["bias"])
        y = y @ p["pwconv2"]["kernel"] + p["pwconv2"]["bias"]
        return x + y * p["gamma"]

    gn = (1, 2, 3)
    L = len(cfg.dims)
    x = gelu(conv(image, params["stem"], 1, "SAME"))
    skips = []
    for i in range(L):
        if i == 0:
            x = norm(conv(x, params["down0_conv"], 4, "VALID"), params["down0_norm"], gn, 1e-5)
        else:
            x = conv(norm(x, params[f"down{i}_norm"], gn, 1e-5), params[f"down{i}_conv"], 2, "VALID")
        for j in range(cfg.enc_depths[i]):
            x = block(x, params[f"enc{i}_block{j}"])
        skips.append(x)
    for i in reversed(range(L - 1)):
        x = conv_t(norm(x, params[f"up{i}_norm"], gn, 1e-5), params[f"up{i}_conv"], 2)
        x = jnp.concatenate([x, skips[i]], axis=-1)
        x = x @ params[f"dec{i}_fuse"]["kernel"] + params[f"dec{i}_fuse"]["bias"]
        for j in range(cfg.dec_depths[i]):
            x = block(x, params[f"dec{i}_block{j}"])
    return conv_t(x, params["head"], 4)


def distinct_copies(image, n: int):
    """``n`` copies of ``image`` that XLA cannot prove equal (so it cannot encode once and
    broadcast); the 1e-30 offsets vanish when added to the pixel values."""
    return image[None] + jnp.arange(n, dtype=image.dtype)[:, None, None, None] * 1e-30


def predict_without_reuse(models, image, bank, *, preset, n: int, R: int, chunk: int):
    """What ``predict(method="dmo")`` costs when F is *not* reused: every (image, motion)
    evaluation runs its own encoder, as an EBM that consumes image and motion jointly must.
    Same result as :func:`dmo_jax.inference.predict`; only for timing."""
    from dmo_jax.networks import DMONet, EBMNet

    ebm, dmo = EBMNet(preset), DMONet(preset)

    def score(motions):
        def one_chunk(m):
            images = distinct_copies(image, m.shape[0])
            feats = ebm.encode(models.ebm, images)
            return jax.vmap(lambda f, x: ebm.energy(models.ebm, f, x[None])[0])(feats, m)

        pad = (-motions.shape[0]) % chunk
        padded = jnp.concatenate([motions, jnp.zeros((pad,) + motions.shape[1:], motions.dtype)])
        return jax.lax.map(one_chunk, padded.reshape((-1, chunk) + motions.shape[1:])).reshape(-1)[:motions.shape[0]]

    _, top = jax.lax.top_k(-score(bank), n)
    cands = [bank[top]]
    for _ in range(R):
        feats = dmo.encode(models.dmo, distinct_copies(image, n))
        cands.append(jax.vmap(lambda f, x: dmo.refine(models.dmo, f, x[None])[0])(feats, cands[-1]))
    cands = jnp.concatenate(cands)
    energies = score(cands)
    return cands[jnp.argmin(energies)]
