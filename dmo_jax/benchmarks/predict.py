"""Latency of ``predict()`` and its parts (``bin/benchmark --only predict``)."""
from __future__ import annotations

import functools
import os
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from dmo_jax.config import get_preset

from .reference import predict_without_reuse
from .timing import compiled_flops, cpu_name, megabytes, peak_bytes, time_call


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

    from dmo_jax.checks import check_arrays
    from dmo_jax.inference import Models, _finite, predict, project_motions, refine, top_candidates
    from dmo_jax.networks import DMONet, EBMNet
    from dmo_jax.vae import VAENet

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
               "peak_mb": megabytes(peak_bytes(lambda m, i, b, k: predict(m, i, b, k, preset=p, method="dmo", n=n, R=1),
                                          models, image, bank, key))}
        rows.append(row)
        if n <= no_reuse_max_n:
            plain = jax.jit(functools.partial(predict_without_reuse, preset=p, n=n, R=1, chunk=min(n, 64) * 4))
            rows.append({"method": "dmo", "n": n, "R": 1, "reuse": False, "stage": "predict",
                         **timed(lambda: plain(models, image, bank)),
                         "peak_mb": megabytes(peak_bytes(plain, models, image, bank))})
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
    paths = _paths_round_robin(models, image, bank, key, p, method_n, repeats)
    # predict()'s value checks on the host (inputs: NaN/range of image and bank; result: finite),
    # the only part of a call outside the compiled program
    result = predict(models, image, bank, key, preset=p, method="dmo", n=method_n, R=1)
    checks_ms = 1e3 * statistics.median(time_call(lambda: (check_arrays(image, bank, key), _finite(result)),
                                                  repeats=repeats, warmup=1))
    return {"preset": p.name, "image_size": p.image_size, "bank": bank_size, "rows": rows, "checks_ms": checks_ms,
            "paths": paths,
            "cpu": cpu_name(), "devices": str(jax.devices()), "loadavg_1min_at_end": os.getloadavg()[0]}


def _paths_round_robin(models, image, bank, key, p, n: int, repeats: int) -> list[dict]:
    """One image's ``predict()`` (``dmo``, top ``n``, R = 1) by each path of scoring the bank: in
    full, in two stages (:class:`~dmo_jax.inference.CoarseRanking`: every 6th pose, keeping 64 or
    32), each from the bare bank and from its :class:`~dmo_jax.inference.BankCache`, timed round-robin
    (one call of each per round), with XLA's FLOP count of each (compiled with the bank in one
    chunk: XLA counts a loop's body once). The cache is made once, outside the timing, as
    ``bin/evaluate`` makes it once per task."""
    from dmo_jax.inference import CoarseRanking, OptimizerSettings, _predict_jit, cache_bank, predict

    cache = jax.block_until_ready(cache_bank(models, bank, preset=p))
    paths = {}
    for coarse in (None, CoarseRanking(6, 64), CoarseRanking(6, 32)):
        name = "full" if coarse is None else "coarse {}/{}".format(*coarse)
        paths[name] = (coarse, bank)
        paths[name + ", cached bank"] = (coarse, cache)
    runs = {name: (lambda c=c, b=b: predict(models, image, b, key, preset=p, method="dmo", n=n, R=1, coarse=c).motion)
            for name, (c, b) in paths.items()}
    times = {name: [] for name in paths}
    for run in runs.values():
        jax.block_until_ready(run())
    for _ in range(repeats):
        for name, run in runs.items():
            times[name] += time_call(run, repeats=1, warmup=0)
    rows = []
    for name, (c, b) in paths.items():
        call = lambda m, i, b, k, c=c: _predict_jit(m, i, b, k, preset=p, method="dmo", n=n, R=1, chunk=len(bank),
                                                     settings=OptimizerSettings(), coarse=c).energies
        rows.append({"path": name, "n": n, "median_ms": 1e3 * statistics.median(times[name]),
                     "gflop": compiled_flops(call, models, image, b, key) / 1e9})
    return rows


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
    if r.get("paths"):
        full, *others = r["paths"]
        for row in others:
            lines.append(f"predict(), dmo n = {row['n']}, {row['path']} against full: {row['median_ms']:.0f} "
                         f"against {full['median_ms']:.0f} ms ({full['median_ms'] / row['median_ms']:.1f}x), "
                         f"{row['gflop']:.1f} against {full['gflop']:.1f} GFLOP")
    if "checks_ms" in r:
        lines.append(f"predict()'s value checks on the host (image, bank, result): {r['checks_ms']:.2f} ms per call")
    for stage, _, n in sorted(k for k in ms if k[1] == "langevin"):
        if (stage, "dmo", n) in ms:
            lines.append(f"{stage}, n = {n}: 100-step Langevin / DMO (R = 1) wall time = "
                         f"{ms[stage, 'langevin', n] / ms[stage, 'dmo', n]:.1f}x")
    return "\n".join(lines)
