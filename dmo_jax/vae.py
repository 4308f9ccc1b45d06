"""ACTOR-style motion VAE (docs/method.md, "Motion VAE"), trained on motions only.

Encoder: the 10 pose numbers (uv, z, rotation, grasp; not time) of each of the 101 steps
-> MLP 10 -> 256 -> 512 -> d (GELU); two learned tokens (mu, sigma) are prepended, sinusoidal
positions added (+ dropout), then a post-norm Transformer encoder (as torch's
``TransformerEncoderLayer``: d, heads, FF, GELU, dropout); outputs 0 and 1 are mu and logvar.

Decoder: memory = z + learned bias (one token); queries = positional encodings of the
101 steps (+ dropout); post-norm Transformer decoder (self-attention, cross-attention to the
memory, FF); one head per key (Dense d/2 -> PReLU -> Dense k -> PReLU, as the reference).
The decoded motion's time channel is the time grid i / 100.

Sizes for the paper preset give 7,772,178 parameters (the reference count).
"""
from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from envs.motion import NUM_STEPS, POSE_DIM, POSE_KEYS, describe_array, time_grid

from .config import Preset, VAEConfig, get_preset
from .encoder import gelu
from .networks import MLP, MultiHeadAttention, PureNet, sinusoidal_positions

Params = Any
#: Pose keys the VAE models (time is not encoded; it is the fixed grid on output).
VAE_KEYS = ("uv", "z", "rotation", "grasp")


def _pose_features(motions: jnp.ndarray) -> jnp.ndarray:
    """``[..., 101, 11] -> [..., 101, 10]``: uv, z, rotation, grasp (drops time)."""
    return jnp.concatenate([motions[..., POSE_KEYS[k]] for k in VAE_KEYS], axis=-1)


class _FeedForward(nn.Module):
    ff_dim: int
    dropout: float

    @nn.compact
    def __call__(self, x, deterministic):
        y = gelu(nn.Dense(self.ff_dim, name="linear1")(x))
        y = nn.Dropout(self.dropout)(y, deterministic=deterministic)
        return nn.Dense(x.shape[-1], name="linear2")(y)


class EncoderLayer(nn.Module):
    """Post-norm self-attention layer (torch ``TransformerEncoderLayer``, ``norm_first=False``)."""

    cfg: VAEConfig

    @nn.compact
    def __call__(self, x, deterministic: bool = True):
        c = self.cfg
        drop = nn.Dropout(c.dropout)
        a = MultiHeadAttention(c.num_heads, c.dropout, name="self_attn")(x, x, x, deterministic)
        x = nn.LayerNorm(1e-5, name="norm1")(x + drop(a, deterministic=deterministic))
        f = _FeedForward(c.ff_dim, c.dropout, name="ff")(x, deterministic)
        return nn.LayerNorm(1e-5, name="norm2")(x + drop(f, deterministic=deterministic))


class DecoderLayer(nn.Module):
    """Post-norm decoder layer (torch ``TransformerDecoderLayer``, ``norm_first=False``)."""

    cfg: VAEConfig

    @nn.compact
    def __call__(self, x, memory, deterministic: bool = True):
        c = self.cfg
        drop = nn.Dropout(c.dropout)
        a = MultiHeadAttention(c.num_heads, c.dropout, name="self_attn")(x, x, x, deterministic)
        x = nn.LayerNorm(1e-5, name="norm1")(x + drop(a, deterministic=deterministic))
        a = MultiHeadAttention(c.num_heads, c.dropout, name="cross_attn")(x, memory, memory, deterministic)
        x = nn.LayerNorm(1e-5, name="norm2")(x + drop(a, deterministic=deterministic))
        f = _FeedForward(c.ff_dim, c.dropout, name="ff")(x, deterministic)
        return nn.LayerNorm(1e-5, name="norm3")(x + drop(f, deterministic=deterministic))


class MotionVAE(nn.Module):
    """``encode(motions [..., 101, 11]) -> (mu, logvar) [..., d]``; ``decode(z [..., d]) -> motions``."""

    config: VAEConfig

    def setup(self):
        c = self.config
        d = c.d_model
        self.input_mlp = MLP((c.input_hidden[0], c.input_hidden[1], d), final_act=False)
        self.mu_token = self.param("mu_token", nn.initializers.normal(1.0), (d,))
        self.sigma_token = self.param("sigma_token", nn.initializers.normal(1.0), (d,))
        self.encoder_layers = [EncoderLayer(c, name=f"enc{i}") for i in range(c.num_layers)]
        self.latent_bias = self.param("latent_bias", nn.initializers.normal(1.0), (d,))
        self.decoder_layers = [DecoderLayer(c, name=f"dec{i}") for i in range(c.num_layers)]
        self.out_fc0 = {k: nn.Dense(d // 2, name=f"{k}_fc0") for k in VAE_KEYS}
        self.out_act0 = {k: nn.PReLU(negative_slope_init=0.25, name=f"{k}_act0") for k in VAE_KEYS}
        self.out_fc1 = {
            k: nn.Dense(POSE_KEYS[k].stop - POSE_KEYS[k].start, name=f"{k}_fc1") for k in VAE_KEYS
        }
        self.out_act1 = {k: nn.PReLU(negative_slope_init=0.25, name=f"{k}_act1") for k in VAE_KEYS}
        self.dropout = nn.Dropout(c.dropout)

    def encode(self, motions, deterministic: bool = True):
        """``motions [..., 101, 11]`` -> ``(mu, logvar)``, each ``[..., d]``."""
        if motions.shape[-2:] != (NUM_STEPS, POSE_DIM):
            raise ValueError(f"motions must be [..., {NUM_STEPS}, {POSE_DIM}], got {motions.shape}")
        x = self.input_mlp(_pose_features(motions))
        lead = x.shape[:-2]
        special = jnp.broadcast_to(jnp.stack([self.mu_token, self.sigma_token]), lead + (2, x.shape[-1]))
        x = jnp.concatenate([special, x], axis=-2)
        x = x + sinusoidal_positions(x.shape[-2], x.shape[-1])
        x = self.dropout(x, deterministic=deterministic)
        for layer in self.encoder_layers:
            x = layer(x, deterministic)
        return x[..., 0, :], x[..., 1, :]

    def decode(self, z, deterministic: bool = True):
        """``z [..., d]`` -> motions ``[..., 101, 11]`` (time channel = the time grid)."""
        memory = (z + self.latent_bias)[..., None, :]
        q = sinusoidal_positions(NUM_STEPS, z.shape[-1])
        q = self.dropout(jnp.broadcast_to(q, z.shape[:-1] + q.shape), deterministic=deterministic)
        for layer in self.decoder_layers:
            q = layer(q, memory, deterministic)
        parts = {}
        for k in VAE_KEYS:
            h = self.out_act0[k](self.out_fc0[k](q))
            parts[k] = self.out_act1[k](self.out_fc1[k](h))
        parts["time"] = jnp.broadcast_to(jnp.asarray(time_grid(NUM_STEPS))[:, None], q.shape[:-1] + (1,))
        return jnp.concatenate([parts[k] for k in POSE_KEYS], axis=-1)

    def __call__(self, motions, rng_eps, deterministic: bool = True):
        """Reconstruction through a posterior sample: ``(recon, mu, logvar)``."""
        mu, logvar = self.encode(motions, deterministic)
        z = mu + jnp.exp(0.5 * logvar) * jax.random.normal(rng_eps, mu.shape, mu.dtype)
        return self.decode(z, deterministic), mu, logvar


@dataclasses.dataclass(frozen=True)
class VAENet(PureNet):
    """Pure motion VAE: parameters in, arrays out."""

    config: VAEConfig

    @classmethod
    def from_preset(cls, preset: Preset | str = "cpu") -> "VAENet":
        return cls((get_preset(preset) if isinstance(preset, str) else preset).vae)

    @property
    def module(self) -> MotionVAE:
        return MotionVAE(self.config)

    def _example_inputs(self) -> tuple:
        # one motion, the noise key
        return jax.ShapeDtypeStruct((1, NUM_STEPS, POSE_DIM), jnp.float32), jax.eval_shape(jax.random.key, 0)

    def init_at_mean(self, rng, mean_pose) -> Params:
        """Initial parameters whose decoder outputs ``mean_pose [11]`` (the training motions'
        mean per channel; time is ignored) at every step for every latent.

        Each head's last layer starts with a zero kernel and the bias whose PReLU is the mean.
        From the default start the decoder must learn the depth offset (z is about 1.5 m):
        after the cpu preset's 600 steps its reconstructions were still about 10 cm too deep.
        """
        mean_pose = np.asarray(mean_pose, np.float32)
        if mean_pose.shape != (POSE_DIM,) or not np.all(np.isfinite(mean_pose)):
            raise ValueError(f"mean_pose must be {POSE_DIM} finite numbers, got {describe_array(mean_pose)}")
        params = self.init(rng)
        inner = params["params"]
        for k in VAE_KEYS:
            target = mean_pose[POSE_KEYS[k]]
            slope = float(inner[f"{k}_act1"]["negative_slope"])
            bias = np.where(target >= 0, target, target / slope).astype(np.float32)
            inner[f"{k}_fc1"] = {"kernel": jnp.zeros_like(inner[f"{k}_fc1"]["kernel"]), "bias": jnp.asarray(bias)}
        return params

    def encode(self, params, motions, *, train: bool = False, rng=None):
        """``motions [..., 101, 11]`` -> ``(mu, logvar)`` each ``[..., d]``."""
        return self._apply(params, "encode", motions, train=train, rng=rng)

    def decode(self, params, z, *, train: bool = False, rng=None):
        """``z [..., d]`` -> motions ``[..., 101, 11]``."""
        return self._apply(params, "decode", z, train=train, rng=rng)

    def sample_around(self, params, motions, rng, k_sigma: float, num_samples: int | None = None):
        """Decode ``z = mu + k_sigma * sigma * eps`` of each motion's posterior (deterministic net).

        ``motions [..., 101, 11]`` -> ``[..., 101, 11]``, or ``[..., num_samples, 101, 11]``
        when ``num_samples`` is given. ``k_sigma=2`` gives the EBM's VAE negatives,
        ``k_sigma=1`` the DMO's training inputs.
        """
        mu, logvar = self.encode(params, motions)
        if num_samples is not None:
            mu = jnp.broadcast_to(mu[..., None, :], mu.shape[:-1] + (num_samples, mu.shape[-1]))
            logvar = jnp.broadcast_to(logvar[..., None, :], mu.shape)
        eps = jax.random.normal(rng, mu.shape, mu.dtype)
        return self.decode(params, mu + k_sigma * jnp.exp(0.5 * logvar) * eps)
