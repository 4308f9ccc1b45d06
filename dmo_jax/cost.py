"""Paper Table 3: parameters and compute of the EBM for every variant.

Compute is counted by XLA's cost analysis of the compiled computation
(``jax.jit(f).lower(...).compile().cost_analysis()["flops"]``), and MAC = flops / 2.
XLA counts a multiply-add of a matrix product or convolution as 2 flops and an
elementwise op (GELU's erf, softmax's exp, normalisation) as about 1 flop per element, so
the MAC figures include half the elementwise work.

* ``gmac_all``: encode one image + score one motion;
* ``gmac_reuse``: cost of one *extra* motion with F reused, i.e.
  ``cost(energy with n = 2) - cost(energy with n = 1)``. Per-image work inside the head
  (the ViT variant's patch conv on F) is therefore counted once, in ``gmac_all``, as in
  the paper.

Nothing is executed: parameters are abstract (``jax.eval_shape``) and only compiled.

Against the paper (``bin/cost --preset paper``): params and "Reuse" agree (Ours 35.87 M /
0.13 GMac vs 35.84 / 0.11; our MACs include half the elementwise flops), but our "All" is
about half of the paper's 23.62. The paper's count matches ours if transposed convs are
counted as thop counts ``nn.ConvTranspose2d`` (output elements x C_in x k^2, i.e. k^2 times
the real work when stride = kernel): the 4x4/4 head becomes 12.9 G instead of 0.81 G and
the three 2x2/2 up-convs 0.91 G instead of 0.23 G, giving ~23.5 GMac. The ViT variant as
docs/method.md defines it (a 16x16/16 conv on the 128-channel F) has 4.19 M more parameters
than the paper's ViT row.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.motion import NUM_STEPS, POSE_DIM

from .config import VARIANTS, get_preset
from .networks import EBMNet, count_params

#: Paper Table 3 (EBM): params (M), GMac "All", GMac "Reuse".
PAPER_TABLE3 = {
    "concat": (35.84, 23.62, 0.11),
    "wo_concat": (35.68, 23.71, 0.19),
    "gap": (35.68, 23.61, 0.10),
    "vit": (35.87, 24.97, 0.38),
}
VARIANT_LABELS = {"concat": "Ours", "wo_concat": "w/o concat", "gap": "GAP", "vit": "ViT"}


def compiled_flops(fn, *args) -> float:
    """Flops of ``jax.jit(fn)`` compiled for these (abstract) arguments, from XLA's cost analysis."""
    analysis = jax.jit(fn).lower(*args).compile().cost_analysis()
    if isinstance(analysis, (list, tuple)):  # older jax returns one dict per computation
        analysis = analysis[0]
    return float(analysis["flops"])


def variant_cost(preset_name: str, variant: str) -> dict:
    """``{"params_m", "gmac_all", "gmac_reuse"}`` for the EBM of one preset and variant."""
    preset = get_preset(preset_name, variant)
    net = EBMNet(preset)
    params = net.param_shapes()
    s = preset.image_size
    image = jax.ShapeDtypeStruct((s, s, 4), jnp.float32)
    feature = jax.ShapeDtypeStruct((s, s, preset.head.feature_channels), jnp.float32)

    def motions(n):
        return jax.ShapeDtypeStruct((n, NUM_STEPS, POSE_DIM), jnp.float32)

    def full(p, img, m):
        return net.energy(p, net.encode(p, img), m)

    all_flops = compiled_flops(full, params, image, motions(1))
    one = compiled_flops(net.energy, params, feature, motions(1))
    two = compiled_flops(net.energy, params, feature, motions(2))
    return {
        "params_m": count_params(params) / 1e6,
        "gmac_all": all_flops / 2e9,
        "gmac_reuse": (two - one) / 2e9,
    }


def cost_table(preset_name: str = "cpu") -> dict:
    """Table 3 for every variant: ``{variant: {"params_m", "gmac_all", "gmac_reuse"}}``."""
    return {v: variant_cost(preset_name, v) for v in VARIANTS}


def format_table(preset_name: str, table: dict) -> str:
    """Plain-text Table 3; for ``paper`` the paper's numbers are shown beside ours."""
    paper = preset_name == "paper"
    head = f"{'variant':<12}{'Params (M)':>12}{'GMac All':>11}{'GMac Reuse':>12}"
    if paper:
        head += f"   | paper: {'Params':>7}{'All':>8}{'Reuse':>7}"
    lines = [f"EBM cost, preset {preset_name!r} (image {get_preset(preset_name).image_size}px); MAC = XLA flops / 2", head]
    for v, row in table.items():
        line = f"{VARIANT_LABELS[v]:<12}{row['params_m']:>12.2f}{row['gmac_all']:>11.3f}{row['gmac_reuse']:>12.3f}"
        if paper:
            p = PAPER_TABLE3[v]
            line += f"   |        {p[0]:>7.2f}{p[1]:>8.2f}{p[2]:>7.2f}"
        lines.append(line)
    return "\n".join(lines)
