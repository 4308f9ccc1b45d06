"""Encoder-forward benchmark (BENCHMARKS.md) and a plain reference implementation.

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
import functools
import json
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from .config import EncoderConfig, get_preset
from .encoder import ConvNeXtUNet, gelu


# --------------------------------------------------------------------------- timing
def time_call(fn, *args, repeats: int = 10, warmup: int = 2) -> list[float]:
    """Wall-clock seconds of ``fn(*args)`` (blocked until ready) for each of ``repeats`` runs."""
    for _ in range(warmup):
        jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return times


def compiled_flops(fn, *args) -> float:
    analysis = jax.jit(fn).lower(*args).compile().cost_analysis()
    if isinstance(analysis, (list, tuple)):
        analysis = analysis[0]
    return float(analysis["flops"])


# --------------------------------------------------------------------------- plain reference
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


# --------------------------------------------------------------------------- torch
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


# --------------------------------------------------------------------------- benchmark
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
            "cpu": _cpu_name(),
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


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


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


# --------------------------------------------------------------------------- training steps
def training_step_benchmark(preset, repeats: int = 5) -> dict:
    """Seconds per optimiser step of the VAE, EBM and DMO: the real jitted ``train_step`` of
    :mod:`dmo_jax.training` (losses, negative sampling, augmentation, Adam) at the preset's
    sizes and batches, on synthetic data. ``preset`` is a name or a
    :class:`~dmo_jax.config.Preset`. Returns per model the median step time, the compile
    time and the time for the preset's step count.
    """
    from envs.motion import time_grid

    from . import training
    from .data import MotionDataset

    p = get_preset(preset) if isinstance(preset, str) else preset
    s = p.image_size
    rng = np.random.default_rng(0)
    # enough motions for every batch and for the recipe's near negatives (random "neighbours": the
    # cost does not depend on which motions they are)
    n = max(p.train.vae_batch, p.train.ebm_batch, p.train.dmo_batch, p.train.near_pool + 1)
    motions = np.concatenate(
        [rng.uniform(-1, 1, (n, 101, 10)), np.broadcast_to(time_grid()[None, :, None], (n, 101, 1))], axis=-1)
    neighbours = np.stack([rng.permutation(np.delete(np.arange(n), i))[:p.train.near_pool] for i in range(n)])
    data = MotionDataset(rng.uniform(0, 1, (n, s, s, 4)).astype(np.float32), motions.astype(np.float32),
                         neighbours.astype(np.int32))
    camera = (np.array([[s, 0, s / 2], [0, s, s / 2], [0, 0, 1]], np.float32), s)
    vae_params = training.VAENet.from_preset(p).init(jax.random.key(0))
    specs = {"vae": (training.vae_spec(p), None), "ebm": (training.ebm_spec(p, camera=camera), vae_params),
             "dmo": (training.dmo_spec(p), vae_params)}
    result = {"preset": p.name, "image_size": s, "models": {}}
    total = 0.0
    for name, (spec, extra) in specs.items():
        tx = training.make_optimizer(spec.config)
        params = spec.init_fn(jax.random.key(1))
        state = training.TrainState.create(params, tx)
        step = jax.jit(training.make_train_step(spec, tx))
        times = []
        for i in range(repeats + 1):
            batch = data.batch(0, i, spec.batch_size, near=spec.near)
            t = time.perf_counter()
            state, metrics = step(state, batch, jax.random.key(i), extra)
            jax.block_until_ready(metrics)
            times.append(time.perf_counter() - t)
        compile_s, sec = times[0], statistics.median(times[1:])
        result["models"][name] = {"step_s": sec, "compile_s": compile_s, "steps": spec.steps,
                                  "train_s": sec * spec.steps, "batch": spec.batch_size}
        total += sec * spec.steps + compile_s
    result["total_s"] = total
    result["loadavg_1min_at_end"] = os.getloadavg()[0]
    return result


def format_training_step_benchmark(r: dict) -> str:
    lines = [f"training steps, preset {r['preset']!r} (image {r['image_size']}px), load avg {r['loadavg_1min_at_end']:.2f}",
             f"{'model':<6}{'step s':>9}{'compile s':>11}{'steps':>8}{'train s':>10}"]
    for name, m in r["models"].items():
        lines.append(f"{name:<6}{m['step_s']:>9.3f}{m['compile_s']:>11.1f}{m['steps']:>8}{m['train_s']:>10.0f}")
    lines.append(f"total incl. compile: {r['total_s']:.0f} s ({r['total_s'] / 60:.1f} min)")
    return "\n".join(lines)


# --------------------------------------------------------------------------- prediction
def _distinct_copies(image, n: int):
    """``n`` copies of ``image`` that XLA cannot prove equal (so it cannot encode once and
    broadcast); the 1e-30 offsets vanish when added to the pixel values."""
    return image[None] + jnp.arange(n, dtype=image.dtype)[:, None, None, None] * 1e-30


def _predict_without_reuse(models, image, bank, *, preset, n: int, R: int, chunk: int):
    """What ``predict(method="dmo")`` costs when F is *not* reused: every (image, motion)
    evaluation runs its own encoder, as an EBM that consumes image and motion jointly must.
    Same result as :func:`dmo_jax.inference.predict`; only for timing."""
    from .networks import DMONet, EBMNet

    ebm, dmo = EBMNet(preset), DMONet(preset)

    def score(motions):
        def one_chunk(m):
            images = _distinct_copies(image, m.shape[0])
            feats = ebm.encode(models.ebm, images)
            return jax.vmap(lambda f, x: ebm.energy(models.ebm, f, x[None])[0])(feats, m)

        pad = (-motions.shape[0]) % chunk
        padded = jnp.concatenate([motions, jnp.zeros((pad,) + motions.shape[1:], motions.dtype)])
        return jax.lax.map(one_chunk, padded.reshape((-1, chunk) + motions.shape[1:])).reshape(-1)[:motions.shape[0]]

    _, top = jax.lax.top_k(-score(bank), n)
    cands = [bank[top]]
    for _ in range(R):
        feats = dmo.encode(models.dmo, _distinct_copies(image, n))
        cands.append(jax.vmap(lambda f, x: dmo.refine(models.dmo, f, x[None])[0])(feats, cands[-1]))
    cands = jnp.concatenate(cands)
    energies = score(cands)
    return cands[jnp.argmin(energies)]


def _peak_bytes(fn, *args) -> int | None:
    """Temporary + output + argument bytes of the compiled ``fn`` (XLA's memory analysis)."""
    try:
        m = jax.jit(fn).lower(*args).compile().memory_analysis()
        return int(m.temp_size_in_bytes + m.output_size_in_bytes + m.argument_size_in_bytes)
    except Exception:  # not every back-end reports it
        return None


def predict_benchmark(preset: str = "cpu", bank_size: int = 1000, ns=(1, 8, 64, 1000), repeats: int = 10,
                      methods=("sort", "dmo", "gd", "langevin", "vaebm-l", "vaebm-s", "dfo"),
                      method_n: int = 8, no_reuse_max_n: int = 64, ratio_ns=(1, 8, 64)) -> dict:
    """Latency of one image's :func:`dmo_jax.inference.predict` (median of ``repeats`` runs
    after compilation), with randomly initialised networks of ``preset`` (the cost does not
    depend on the weights) and a bank of ``bank_size`` random motions:

    * ``dmo`` at R = 1 for every n in ``ns``, with F reused (as shipped) and without (the
      encoder re-run per evaluation; up to n = ``no_reuse_max_n``);
    * every method of ``methods`` at n = ``method_n`` (the baselines at the paper's 100
      iterations), as a whole ``predict()`` and as :func:`~dmo_jax.inference.refine` alone
      (steps 3-4 from the same top n): the optimiser's own cost, without the bank scoring
      that every method shares; and ``dmo`` against ``langevin`` alone at every n of
      ``ratio_ns``, since the DMO's fixed cost (its encoder) weighs less as n grows.

    Peak memory is XLA's compiled memory analysis (arguments + outputs + temporaries).
    """
    from envs.motion import time_grid

    from .checks import check_arrays
    from .inference import Models, _finite, predict, project_motions, refine, top_candidates
    from .networks import DMONet, EBMNet
    from .vae import VAENet

    p = get_preset(preset)
    rng = np.random.default_rng(0)
    models = Models(EBMNet(p).init(jax.random.key(0)), DMONet(p).init(jax.random.key(1)),
                    VAENet.from_preset(p).init(jax.random.key(2)))
    image = jnp.asarray(rng.uniform(0, 1, (p.image_size, p.image_size, 4)), jnp.float32)
    bank = np.concatenate([rng.uniform(-0.8, 0.8, (bank_size, 101, 2)), rng.uniform(0.8, 1.6, (bank_size, 101, 1)),
                           rng.normal(size=(bank_size, 101, 6)), rng.uniform(0, 1, (bank_size, 101, 1)),
                           np.broadcast_to(time_grid()[None, :, None], (bank_size, 101, 1))], axis=-1)
    bank = project_motions(jnp.asarray(bank, jnp.float32))
    key = jax.random.key(0)

    def timed(fn):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        first = time.perf_counter() - t0
        return {"median_ms": 1e3 * statistics.median(time_call(fn, repeats=repeats, warmup=1)),
                "first_call_s": round(first, 2)}

    rows = []
    for n in ns:
        run = lambda n=n: predict(models, image, bank, key, preset=p, method="dmo", n=n, R=1).motion
        row = {"method": "dmo", "n": n, "R": 1, "reuse": True, "stage": "predict", **timed(run),
               "peak_mb": _mb(_peak_bytes(lambda m, i, b, k: predict(m, i, b, k, preset=p, method="dmo", n=n, R=1),
                                          models, image, bank, key))}
        rows.append(row)
        if n <= no_reuse_max_n:
            plain = jax.jit(functools.partial(_predict_without_reuse, preset=p, n=n, R=1, chunk=min(n, 64) * 4))
            rows.append({"method": "dmo", "n": n, "R": 1, "reuse": False, "stage": "predict",
                         **timed(lambda: plain(models, image, bank)),
                         "peak_mb": _mb(_peak_bytes(plain, models, image, bank))})
    for method in [m for m in methods if not (m == "dmo" and method_n in ns)]:  # dmo at method_n: timed above
        run = lambda m=method: predict(models, image, bank, key, preset=p, method=m, n=method_n, R=1).motion
        rows.append({"method": method, "n": method_n, "R": 1 if method == "dmo" else None, "reuse": True,
                     "stage": "predict", **timed(run)})
    # The optimisers alone, timed round-robin (one call of each per round) so that a change in the
    # machine's load shifts every method alike and their ratios stay comparable.
    for n in sorted({method_n, *ratio_ns}):
        chosen = methods if n == method_n else [m for m in ("dmo", "langevin") if m in methods]
        start = top_candidates(models, image, bank, preset=p, n=n)
        runs = {m: (lambda m=m: refine(models, image, start, key, preset=p, method=m, R=1).motion) for m in chosen}
        first = {}
        for method, run in runs.items():
            t0 = time.perf_counter()
            jax.block_until_ready(run())
            first[method] = round(time.perf_counter() - t0, 2)
        times = {m: [] for m in chosen}
        for _ in range(repeats):
            for method, run in runs.items():
                times[method] += time_call(run, repeats=1, warmup=0)
        for method in chosen:
            rows.append({"method": method, "n": n, "R": 1 if method == "dmo" else None, "reuse": True,
                         "stage": "refine", "median_ms": 1e3 * statistics.median(times[method]),
                         "first_call_s": first[method]})
    bank_scoring = _bank_scoring_round_robin(models, image, bank, p, method_n, repeats)
    # predict()'s value checks on the host (inputs: NaN/range of image and bank; result: finite),
    # the only part of a call outside the compiled program
    result = predict(models, image, bank, key, preset=p, method="dmo", n=method_n, R=1)
    checks_ms = 1e3 * statistics.median(time_call(lambda: (check_arrays(image, bank, key), _finite(result)),
                                                  repeats=repeats, warmup=1))
    return {"preset": p.name, "image_size": p.image_size, "bank": bank_size, "rows": rows, "checks_ms": checks_ms,
            "bank_scoring": bank_scoring,
            "cpu": _cpu_name(), "devices": str(jax.devices()), "loadavg_1min_at_end": os.getloadavg()[0]}


def _bank_scoring_round_robin(models, image, bank, p, n: int, repeats: int) -> list[dict]:
    """One image's bank scoring (:func:`~dmo_jax.inference.top_candidates`, top ``n``) in full and
    in two stages (:class:`~dmo_jax.inference.CoarseRanking`, keeping 64 and 32), timed round-robin, with
    XLA's FLOP count of each (compiled with the bank in one chunk: XLA counts a loop's body once)."""
    from .inference import CoarseRanking, _top_candidates_jit, top_candidates

    coarse = (CoarseRanking(), CoarseRanking(keep=32))
    paths = {"full": None, **{"coarse {}/{}".format(*c): c for c in coarse}}
    runs = {name: (lambda c=c: top_candidates(models, image, bank, preset=p, n=n, coarse=c).motions)
            for name, c in paths.items()}
    times = {name: [] for name in paths}
    for run in runs.values():
        jax.block_until_ready(run())
    for _ in range(repeats):
        for name, run in runs.items():
            times[name] += time_call(run, repeats=1, warmup=0)
    rows = []
    for name, c in paths.items():
        scoring = lambda m, i, b, c=c: _top_candidates_jit(m, i, b, preset=p, n=n, chunk=b.shape[0], coarse=c).energies
        rows.append({"path": name, "n": n, "median_ms": 1e3 * statistics.median(times[name]),
                     "gflop": compiled_flops(scoring, models, image, bank) / 1e9})
    return rows


def device_benchmark(small: bool | None = None, repeats: int = 5) -> dict:
    """The accelerator check, one command: :func:`predict_benchmark` (``dmo``, n = 8 and 64, bank
    1,000, medians after compilation) of the ``cpu`` and ``paper`` presets, one training step of
    each ``paper``-preset model (:func:`training_step_benchmark`) and 100 MJX episodes of the
    scripted pick-up. ``small`` (default: on a CPU) keeps it to minutes: the ``cpu`` preset's
    predict, the ``tiny`` preset's training steps and 8 episodes."""
    from envs.benchmark import benchmark_execution

    small = jax.default_backend() == "cpu" if small is None else small
    presets = ("cpu",) if small else ("cpu", "paper")
    return {
        "device": jax.devices()[0].device_kind, "backend": jax.default_backend(), "small": small,
        "predict": {p: predict_benchmark(p, ns=(8, 64), repeats=repeats, methods=("dmo",), no_reuse_max_n=0,
                                         ratio_ns=()) for p in presets},
        "train_step": training_step_benchmark("tiny" if small else "paper", repeats),
        "execution": benchmark_execution(8 if small else 100, repeats=min(repeats, 3), backends=("mjx",)),
    }


def format_device_benchmark(r: dict) -> str:
    parts = [f"device check on {r['device']} ({r['backend']}){', small sizes' if r['small'] else ''}"]
    parts += [format_predict_benchmark(p) for p in r["predict"].values()]
    parts.append(format_training_step_benchmark(r["train_step"]))
    parts += ["execution\n" + "\n".join(json.dumps(row) for row in r["execution"])]
    return "\n\n".join(parts)


def _mb(nbytes):
    return None if nbytes is None else round(nbytes / 2**20, 1)


def format_predict_benchmark(r: dict) -> str:
    lines = [f"predict(), preset {r['preset']!r} ({r['image_size']}px), bank {r['bank']}, {r['devices']}, "
             f"load avg {r['loadavg_1min_at_end']:.2f}; stage 'refine' = refine() alone from the top n",
             "| stage | method | n | R | F reused | median ms | first call s | peak MB |",
             "|---|---|---|---|---|---|---|---|"]
    for row in r["rows"]:
        lines.append(f"| {row['stage']} | {row['method']} | {row['n']} | {row['R'] if row['R'] is not None else '–'} | "
                     f"{'yes' if row['reuse'] else 'no'} | {row['median_ms']:.1f} | {row['first_call_s']:.1f} | "
                     f"{row.get('peak_mb') if row.get('peak_mb') is not None else '–'} |")
    ms = {(row["stage"], row["method"], row["n"]): row["median_ms"] for row in r["rows"] if row["reuse"]}
    if r.get("bank_scoring"):
        full, *others = r["bank_scoring"]
        for row in others:
            lines.append(f"bank scoring for the top {row['n']}, {row['path']} against full: {row['median_ms']:.0f} "
                         f"against {full['median_ms']:.0f} ms ({full['median_ms'] / row['median_ms']:.1f}x), "
                         f"{row['gflop']:.1f} against {full['gflop']:.1f} GFLOP")
    if "checks_ms" in r:
        lines.append(f"predict()'s value checks on the host (image, bank, result): {r['checks_ms']:.2f} ms per call")
    for stage, _, n in sorted(k for k in ms if k[1] == "langevin"):
        if (stage, "dmo", n) in ms:
            lines.append(f"{stage}, n = {n}: 100-step Langevin / DMO (R = 1) wall time = "
                         f"{ms[stage, 'langevin', n] / ms[stage, 'dmo', n]:.1f}x")
    return "\n".join(lines)
