"""``bin/benchmark``: the speed measurements of BENCHMARKS.md (the measuring is ``dmo_jax.benchmarks``'s
and ``envs.benchmark``'s)."""
from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

from dmo_jax.commands.common import fail, write_json
from envs.commands.common import check_output_file, positive
from envs.platform import setup

BENCHMARK_SECTIONS = ("encoder", "train-step", "execution", "predict", "data")
#: Sections run only when asked for (``--only``).
EXTRA_SECTIONS = ("device",)


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    from dmo_jax.config import PRESETS

    parser = argparse.ArgumentParser(description="Benchmarks of dmo-jax (see BENCHMARKS.md).")
    parser.add_argument("--only", choices=BENCHMARK_SECTIONS + EXTRA_SECTIONS,
                        help="one section (default: every section, each in its own process so that its peak "
                        "memory is its own). encoder: one image's encoder forward; train-step: VAE/EBM/DMO "
                        "optimiser steps; execution: physics back-ends (native MuJoCo, MJX) on the scripted "
                        "pick-up; predict: predict() latency per n and per method, with and without F reuse; "
                        "data: demonstration generation (expert, physics, rendering); device (only when asked "
                        "for): the accelerator check, predict() of the cpu and paper presets at n = 8 and 64, a "
                        "paper-preset training step of each model and 100 MJX episodes (on a CPU: the cpu "
                        "preset's predict, tiny training steps and 8 episodes)")
    parser.add_argument("--episodes", type=int, default=64, help="episodes per batch (execution, data)")
    parser.add_argument("--preset", choices=list(PRESETS),
                        help="default: paper for encoder, cpu for train-step and predict")
    parser.add_argument("--repeats", type=int, default=10, help="timed runs per measurement (default 10)")
    parser.add_argument("--torch-reference", action="store_true", help="also time a same-sized PyTorch U-Net")
    parser.add_argument("--json", action="store_true", help="print JSON instead of tables")
    parser.add_argument("--out", help="also write the JSON to this file")
    args = parser.parse_args(argv)
    positive("--repeats", args.repeats)
    positive("--episodes", args.episodes)
    if args.out:
        check_output_file(args.out, "--out")

    if args.only is None:
        result = {}
        for section in BENCHMARK_SECTIONS:
            try:
                result[section] = _section_in_subprocess(section, args)
            except RuntimeError as err:
                if args.out and result:  # keep the sections already measured
                    write_json(args.out, result)
                fail(f"{err}{f'; the sections before it are in {args.out}' if args.out and result else ''}")
        text = lambda r: "\n\n".join(_format(s, r[s]) for s in BENCHMARK_SECTIONS)  # noqa: E731
    else:
        result = _section(args.only, args)
        text = functools.partial(_format, args.only)
    print(json.dumps(result, indent=1) if args.json else text(result))
    if args.out:
        write_json(args.out, result)


def _section(section: str, args) -> dict:
    """One section's measurements, plus this process's peak resident memory (``peak_rss_mb``)."""
    import resource

    from dmo_jax.benchmarks import device, encoder, predict, training_step

    if section == "encoder":
        result = encoder.encoder_benchmark(args.preset or "paper", args.repeats, with_torch=args.torch_reference)
    elif section == "train-step":
        result = training_step.training_step_benchmark(args.preset or "cpu", args.repeats)
    elif section == "predict":
        result = predict.predict_benchmark(args.preset or "cpu", repeats=args.repeats)
    elif section == "execution":
        from envs.benchmark import benchmark_execution

        result = {"rows": benchmark_execution(args.episodes, min(args.repeats, 3))}
    elif section == "device":
        result = device.device_benchmark(repeats=args.repeats)
    else:
        from envs.benchmark import benchmark_data_generation

        result = benchmark_data_generation(episodes=args.episodes)
    # ru_maxrss is in KiB on Linux
    return {**result, "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def _section_in_subprocess(section: str, args) -> dict:
    import os
    import subprocess

    root = Path(__file__).resolve().parents[2]
    argv = ["--only", section, "--json", "--repeats", str(args.repeats), "--episodes", str(args.episodes)]
    argv += (["--preset", args.preset] if args.preset else []) + (["--torch-reference"] if args.torch_reference else [])
    print(f"[benchmark] {section} ...", file=sys.stderr)
    t0 = time.perf_counter()
    code = "from dmo_jax.commands.benchmark import main; main()"  # main sets the process up first
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, "-c", code, *argv], cwd=root, env=env, stdout=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark section {section!r} failed (exit status {proc.returncode}); rerun it alone "
                           f"with bin/benchmark --only {section}")
    print(f"[benchmark] {section} done in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return json.loads(proc.stdout)


def _format(section: str, result: dict) -> str:
    from dmo_jax.benchmarks import device, encoder, predict, training_step

    if section == "encoder":
        text = encoder.format_encoder_benchmark(result)
    elif section == "train-step":
        text = training_step.format_training_step_benchmark(result)
    elif section == "predict":
        text = predict.format_predict_benchmark(result)
    elif section == "execution":
        text = "execution\n" + "\n".join(json.dumps(r) for r in result["rows"])
    elif section == "device":
        text = device.format_device_benchmark(result)
    else:
        text = (f"data generation: {result['episodes']} episodes of {result['task']} at {result['image_size']}px in "
                f"{result['seconds']:.1f} s = {result['episodes_per_s']:.2f} episodes/s")
    return f"{text}\npeak resident memory of the process: {result['peak_rss_mb']:.0f} MB"
