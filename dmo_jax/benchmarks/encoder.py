"""Encoder-forward benchmark (``bin/benchmark --only encoder``).

``encoder_benchmark`` times one image's forward pass of the ConvNeXt U-Net (median of
repeated runs after compilation) in several implementations that compute the same
function from the same parameters:

* ``plain``: the textbook XLA formulation, what a direct Flax port gives
  (``lax.conv`` for stride = kernel convs, ``lax.conv_transpose`` for the transposed ones,
  a grouped convolution for the depthwise 7x7, two-pass normalisation);
* ``fast``: :class:`dmo_jax.encoder.ConvNeXtUNet` as shipped (float32);
* ``fast, dw=conv``: the same but with the grouped depthwise convolution, isolating the
  effect of the shifted-sum depthwise conv;
* ``fast, bf16``: bf16 matrix products / convolutions, with its error against float32.

Throughput is reported as GFLOP/s of XLA's flop count of the ``fast`` computation,
next to a measured float32 matmul peak of this machine. With ``with_torch`` a
same-sized PyTorch U-Net is timed in the same rounds (only if torch is installed). All
implementations and a 2048^3 float32 matmul (the peak) are timed round-robin, so a
change of load on the machine affects them alike.
"""
from __future__ import annotations

import dataclasses
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from dmo_jax.config import get_preset
from dmo_jax.encoder import ConvNeXtUNet

from .reference import plain_encoder_forward
from .timing import compiled_flops, cpu_name, time_call


def _torch_unet(cfg: EncoderConfig, image_size: int):
    """A same-sized PyTorch U-Net (NCHW, float32, inference) as a function returning the
    seconds of one forward pass on a ``[1, 4, S, S]`` image (after 2 warm-up runs); None
    if torch is not installed."""
    try:
        import torch
        from torch import nn
    except ImportError:
        return None

    class Block(nn.Module):
        def __init__(self, c):
            super().__init__()
            self.dw = nn.Conv2d(c, c, 7, padding=3, groups=c)
            self.norm = nn.LayerNorm(c, eps=1e-6)
            self.fc1, self.fc2 = nn.Linear(c, 4 * c), nn.Linear(4 * c, c)
            self.gamma = nn.Parameter(torch.full((c,), 1e-6))

        def forward(self, x):
            y = self.dw(x).permute(0, 2, 3, 1)
            y = self.gamma * self.fc2(nn.functional.gelu(self.fc1(self.norm(y))))
            return x + y.permute(0, 3, 1, 2)

    class UNet(nn.Module):
        def __init__(self):
            super().__init__()
            d = cfg.dims
            self.stem = nn.Conv2d(4, d[0], 3, padding=1)
            self.down = nn.ModuleList(
                [nn.Sequential(nn.Conv2d(d[0], d[0], 4, 4), nn.GroupNorm(1, d[0]))]
                + [nn.Sequential(nn.GroupNorm(1, d[i - 1]), nn.Conv2d(d[i - 1], d[i], 2, 2)) for i in range(1, len(d))]
            )
            self.enc = nn.ModuleList([nn.Sequential(*[Block(d[i]) for _ in range(n)]) for i, n in enumerate(cfg.enc_depths)])
            self.up = nn.ModuleList(
                [nn.Sequential(nn.GroupNorm(1, d[i + 1]), nn.ConvTranspose2d(d[i + 1], d[i], 2, 2)) for i in range(len(d) - 1)]
            )
            self.fuse = nn.ModuleList([nn.Conv2d(2 * d[i], d[i], 1) for i in range(len(d) - 1)])
            self.dec = nn.ModuleList([nn.Sequential(*[Block(d[i]) for _ in range(n)]) for i, n in enumerate(cfg.dec_depths)])
            self.head = nn.ConvTranspose2d(d[0], cfg.out_dim, 4, 4)

        def forward(self, x):
            x = nn.functional.gelu(self.stem(x))
            skips = []
            for down, enc in zip(self.down, self.enc):
                x = enc(down(x))
                skips.append(x)
            for i in reversed(range(len(self.up))):
                x = self.dec[i](self.fuse[i](torch.cat([self.up[i](x), skips[i]], 1)))
            return self.head(x)

    model = UNet().eval()
    x = torch.rand(1, 4, image_size, image_size)

    @torch.inference_mode()
    def run() -> float:
        t = time.perf_counter()
        model(x)
        return time.perf_counter() - t

    run(), run()
    run.info = {"threads": torch.get_num_threads(), "version": torch.__version__}
    return run


def encoder_benchmark(preset: str = "paper", repeats: int = 10, with_torch: bool = False,
                      implementations: tuple[str, ...] = ("plain", "fast", "fast_dwconv", "fast_bf16")) -> dict:
    """Time the encoder forward on one ``[1, S, S, 4]`` image; see the module docstring."""
    p = get_preset(preset)
    cfg = dataclasses.replace(p.encoder, compute_dtype="float32", dwconv_impl="shift")
    s = p.image_size
    image = jax.random.uniform(jax.random.key(1), (1, s, s, 4), jnp.float32)
    model = ConvNeXtUNet(cfg)
    params = jax.jit(model.init)(jax.random.key(0), image)
    # Layer scale 1e-6 makes every block nearly the identity; use O(1) values so that the
    # accuracy comparison sees every layer.
    params = jax.tree_util.tree_map_with_path(
        lambda path, x: jnp.full_like(x, 0.5) if path[-1].key == "gamma" else x, params
    )
    fast_flops = compiled_flops(model.apply, params, image)

    def module_fn(c):
        return jax.jit(ConvNeXtUNet(c).apply)

    fns = {
        "plain": (jax.jit(lambda prm, x: plain_encoder_forward(prm["params"], x, cfg)), "plain XLA convs (direct port)"),
        "fast": (module_fn(cfg), "ConvNeXtUNet (default, float32)"),
        "fast_dwconv": (module_fn(dataclasses.replace(cfg, dwconv_impl="conv")), "ConvNeXtUNet, grouped-conv depthwise"),
        "fast_bf16": (module_fn(dataclasses.replace(cfg, compute_dtype="bfloat16")), "ConvNeXtUNet, bf16 compute"),
    }
    reference = np.asarray(fns["fast"][0](params, image), np.float64)
    scale = float(np.sqrt(np.mean(reference**2)))
    rows = {}
    for name in implementations:
        fn, label = fns[name]
        out = np.asarray(fn(params, image), np.float64)  # compiles
        rows[name] = {"label": label, "rel_rms_error_vs_fast": float(np.sqrt(np.mean((out - reference) ** 2)) / scale)}

    # Round-robin timing: each round runs every implementation once and one matmul, so that
    # a change of load on the machine hits all of them alike.
    n = 2048
    a = jax.random.normal(jax.random.key(2), (n, n), jnp.float32)
    matmul = jax.jit(jnp.dot)
    times = {name: [] for name in rows}
    matmul_times, torch_times = [], []
    torch_model = _torch_unet(cfg, s) if with_torch else None
    for _ in range(repeats):
        for name in rows:
            times[name] += time_call(fns[name][0], params, image, repeats=1, warmup=1 if not times[name] else 0)
        matmul_times += time_call(matmul, a, a, repeats=1, warmup=0 if matmul_times else 1)
        if torch_model is not None:
            torch_times.append(torch_model())
    for name, row in rows.items():
        row["seconds"] = statistics.median(times[name])
        row["seconds_min"] = min(times[name])
        row["gflops_per_s"] = fast_flops / row["seconds"] / 1e9
    peak = 2 * n**3 / statistics.median(matmul_times) / 1e9
    result = {
        "preset": preset,
        "image_size": s,
        "gflop_per_image": fast_flops / 1e9,
        "matmul_peak_gflops_f32": peak,
        "rows": rows,
        "machine": {
            "cpu": cpu_name(),
            "cores": os.cpu_count(),
            "loadavg_1min_at_end": os.getloadavg()[0],
            "jax": jax.__version__,
            "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "python": platform.python_version(),
        },
    }
    if with_torch:
        result["torch"] = None if torch_model is None else dict(seconds=statistics.median(torch_times), **torch_model.info)
    return result


def format_encoder_benchmark(r: dict) -> str:
    peak = r["matmul_peak_gflops_f32"]
    lines = [
        f"encoder forward, preset {r['preset']!r}, one {r['image_size']}x{r['image_size']} image, "
        f"{r['gflop_per_image']:.2f} GFLOP (XLA count of the fast path)",
        f"machine: {r['machine']['cpu']}, {r['machine']['cores']} cores, jax {r['machine']['jax']}, "
        f"XLA_FLAGS={r['machine']['xla_flags']!r}, load avg {r['machine']['loadavg_1min_at_end']:.2f}",
        f"float32 matmul peak (2048^3): {peak:.1f} GFLOP/s",
        f"{'implementation':<40}{'median s':>10}{'GFLOP/s':>10}{'% peak':>8}{'rel RMS err':>13}",
    ]
    for row in r["rows"].values():
        lines.append(
            f"{row['label']:<40}{row['seconds']:>10.3f}{row['gflops_per_s']:>10.1f}"
            f"{100 * row['gflops_per_s'] / peak:>7.0f}%{row['rel_rms_error_vs_fast']:>13.1e}"
        )
    t = r.get("torch")
    if "torch" in r:
        if t is None:
            lines.append("PyTorch reference: torch not installed")
        else:
            lines.append(
                f"{'PyTorch ' + t['version'] + ' (' + str(t['threads']) + ' threads)':<40}{t['seconds']:>10.3f}"
                f"{r['gflop_per_image'] / t['seconds']:>10.1f}{100 * r['gflop_per_image'] / t['seconds'] / peak:>7.0f}%"
            )
    return "\n".join(lines)
