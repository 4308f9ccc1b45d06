"""The accelerator check in one command (``bin/benchmark --only device``)."""
from __future__ import annotations

import json

import jax

from .predict import format_predict_benchmark, predict_benchmark
from .training_step import format_training_step_benchmark, training_step_benchmark


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
