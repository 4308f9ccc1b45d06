"""The value, dtype and parameter checks of :func:`dmo_jax.inference.predict` and its halves:
each raises ``ValueError`` in one line naming what is wrong and what was expected."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from envs.motion import NUM_STEPS, POSE_DIM, count_non_finite, describe_array

from .config import Preset
from .networks import DMONet, EBMNet
from .vae import VAENet


def is_concrete(x) -> bool:
    """False for a tracer (``predict`` called inside the caller's ``jax.jit``): its values are
    unknown, only its shape and dtype can be checked."""
    return not isinstance(x, jax.core.Tracer)


def is_integer(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def check_arrays(image, bank, key, bank_name: str = "bank") -> None:
    """dtype checks (always) and value checks (concrete arrays only) of :func:`predict`'s
    arrays (``image`` or ``key`` None: not checked); raises ``ValueError`` naming what is wrong and what was
    expected (the motions as ``bank_name``)."""
    if image is not None and not jnp.issubdtype(image.dtype, jnp.floating):
        raise ValueError(f"image must be floating-point (RGB in [0, 1] + depth mapped to [0, 1], see "
                         f"dmo_jax.data.network_image), got {describe_array(image)}")
    if not jnp.issubdtype(bank.dtype, jnp.floating):
        raise ValueError(f"{bank_name} must be floating-point [N, {NUM_STEPS}, {POSE_DIM}] motions, got "
                         f"{describe_array(bank)}")
    if key is not None:
        typed_key = jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
        if not ((typed_key and key.shape == ()) or (key.dtype == jnp.uint32 and key.shape == (2,))):
            raise ValueError(f"key must be one PRNG key (jax.random.key(seed)), got {describe_array(key)}")
    if image is not None and is_concrete(image):
        bad = count_non_finite(image)
        if bad:
            raise ValueError(f"image contains {bad} NaN or inf value(s); expected finite values in [0, 1]")
        low, high = float(np.min(np.asarray(image))), float(np.max(np.asarray(image)))
        if low < 0.0 or high > 1.0:
            raise ValueError(f"image values must lie in [0, 1] (dmo_jax.data.network_image), got min {low:.4g}, "
                             f"max {high:.4g}")
    if is_concrete(bank):
        bad = count_non_finite(bank)
        if bad:
            raise ValueError(f"{bank_name} contains {bad} NaN or inf value(s); expected finite motions")


def _shape_table(tree) -> dict[str, tuple]:
    leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    return {jax.tree_util.keystr(path): tuple(getattr(leaf, "shape", np.shape(leaf))) for path, leaf in leaves}


def _signature(tree) -> tuple:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return treedef, tuple(tuple(getattr(leaf, "shape", np.shape(leaf))) for leaf in leaves)


def _expected_params(preset: Preset, which: str):
    if which == "vae":
        return VAENet(preset.vae).param_shapes()
    return (EBMNet if which == "ebm" else DMONet)(preset).param_shapes()


@functools.lru_cache(maxsize=None)
def _expected_signature(preset: Preset, which: str) -> tuple:
    return _signature(_expected_params(preset, which))


def check_params(params, preset: Preset, which: str) -> None:
    """Raise ``ValueError`` unless ``params`` (``Models.<which>``) have the parameter names and
    shapes of ``preset``'s network, e.g. a checkpoint of another preset or variant."""
    if _signature(params) == _expected_signature(preset, which):  # the fast path of every call
        return
    got, want = _shape_table(params), _shape_table(_expected_params(preset, which))
    if got == want:
        return
    wrong = [k for k in want if k in got and got[k] != want[k]]
    missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
    parts = []
    if wrong:
        parts.append(f"{wrong[0]} is {list(got[wrong[0]])}, expected {list(want[wrong[0]])}")
    if missing:
        parts.append(f"{len(missing)} parameter(s) missing (e.g. {missing[0]})")
    if extra:
        parts.append(f"{len(extra)} unexpected parameter(s) (e.g. {extra[0]})")
    detail = "; ".join(parts)
    raise ValueError(f"Models.{which} do not fit preset {preset.name!r} (variant {preset.variant!r}, "
                     f"{preset.image_size}px): {detail}; were they trained with another preset or variant?")
