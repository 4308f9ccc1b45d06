"""Library functions behind the method's commands (``bin/train_all``, ``bin/evaluate``,
``bin/cost``, ``bin/benchmark``, ``bin/compare``)."""
from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path


def _fail(message: str) -> None:
    from envs.cli import fail

    fail(message)


def _write_json(path: str, payload) -> None:
    from envs.cli import write_json

    write_json(path, payload)


def train_all_main(argv: list[str] | None = None) -> None:
    from dmo_jax.config import VARIANTS
    from envs.cli import task_help
    from dmo_jax.losses import NEGATIVE_MODES

    parser = argparse.ArgumentParser(
        description="Per task: generate the data if missing, then train VAE -> EBM -> DMO, skipping what is "
        "trained and resuming what was interrupted.")
    _add_recipe_argument(parser)
    parser.add_argument("--tasks", default="all", help=task_help() + " (default all)")
    _add_preset_argument(parser)
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--workdir", default="runs", help="checkpoints and metrics (default ./runs)")
    parser.add_argument("--variant", default="concat", choices=VARIANTS,
                        help="architecture (paper Table 2): concat = the paper's model (default)")
    parser.add_argument("--negatives", default="in-data+vae", choices=NEGATIVE_MODES,
                        help="the EBM's negatives (paper Table 4): in-data+vae (default) or only-vae")
    parser.add_argument("--dmo-steps", type=int, help="R, DMO iterations unrolled in training (default: preset's)")
    _add_set_argument(parser, "replace a setting of the preset; a run of more steps continues a finished one in "
                      "the same --workdir")
    parser.add_argument("--seed", type=int, default=0, help="training seed: initialisation, batches, draws (default 0)")
    parser.add_argument("--json", help="also write the summary as JSON to this file")
    args = parser.parse_args(argv)
    if args.dmo_steps is not None and args.dmo_steps < 1:
        _fail(f"--dmo-steps must be at least 1, got {args.dmo_steps}")

    from envs.cli import check_output_file, check_seed, default_data_dir, make_output_dir, task_names
    from envs.dataset import DatasetError, split_dir
    from dmo_jax import training, workflow
    from dmo_jax.config import get_preset
    from envs.platform import enable_compilation_cache

    check_seed("--seed", args.seed)
    enable_compilation_cache()
    try:
        preset = get_preset(args.preset, args.variant, args.recipe).with_overrides(args.set)
    except ValueError as err:
        _fail(str(err))
    names = task_names(args.tasks)
    data = args.data or default_data_dir(preset.image_size)
    if args.json:
        check_output_file(args.json, "--json")
    make_output_dir(args.workdir, "--workdir")
    if any(not (split_dir(data, n, s) / "meta.json").is_file() for n in names for s in ("train", "test")):
        make_output_dir(data, "--data")  # missing splits are generated there
    try:
        training.maybe_initialize_distributed()
    except training.TrainingError as err:
        _fail(str(err))
    summaries, start = {}, time.perf_counter()
    for name in names:
        print(f"[{name}] preset {preset.name}, recipe {preset.recipe}, variant {preset.variant}, "
              f"negatives {args.negatives}"
              + (f", {', '.join(args.set)}" if args.set else ""), file=sys.stderr)
        try:
            summaries[name] = workflow.train_task(name, preset, data, args.workdir, args.negatives, args.dmo_steps,
                                                  args.seed, log=lambda m: print(m, file=sys.stderr))
        except (DatasetError, training.TrainingError, ValueError, RuntimeError, OSError) as err:
            _fail(f"{name}: {err}")
    print(_summary_table(summaries))
    print(f"total wall time {time.perf_counter() - start:.0f} s")
    if args.json:
        _write_json(args.json, summaries)


def _add_preset_argument(parser) -> None:
    from dmo_jax.config import DEFAULT_PRESET, PRESETS

    parser.add_argument("--preset", default=DEFAULT_PRESET, choices=tuple(PRESETS),
                        help=f"network sizes and training settings (default {DEFAULT_PRESET}): tiny for tests, cpu "
                        "for a 2-core CPU at 64 px, paper = the paper's at 256 px")


def _add_set_argument(parser, purpose: str) -> None:
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                        help=f"{purpose}: a training setting (train.FIELD, any dmo_jax.config.TrainConfig field, "
                        "e.g. train.dmo_steps=2400) or how the head reads depth (head.depth_cue=true, "
                        "head.depth_cue_range=0.1); the section may be left out; repeatable")


def _add_recipe_argument(parser, purpose: str = "what the networks train on") -> None:
    from dmo_jax.config import RECIPES

    parser.add_argument("--recipe", choices=RECIPES,
                        help=f"training recipe: {purpose}. paper: the paper's negatives and DMO inputs; bank: "
                        "about half of the EBM's in-data negatives are each scene's nearest training motions, and "
                        "its target ranks every candidate by its distance from the scene's motion (default: the "
                        "preset's own, dmo_jax.config.RECIPES)")


def _summary_table(summaries: dict) -> str:
    rows = ["| task | VAE s | EBM s | DMO s | EBM held-out top-1 | among the 63 nearest: top-1, first choice's error "
            "without the positive (cm) | DMO position error before → after (m) |",
            "|---|---|---|---|---|---|---|"]
    nan = float("nan")
    for name, s in summaries.items():
        dmo, ebm = s["dmo"], s["ebm"]
        before, after = dmo.get("heldout_position_before", nan), dmo.get("heldout_position_after", nan)
        rows.append(f"| {name} | {s['vae']['seconds']:.0f} | {ebm['seconds']:.0f} | {dmo['seconds']:.0f} | "
                    f"{100 * ebm.get('heldout_top1', nan):.1f} % | {100 * ebm.get('heldout_near_top1', nan):.0f} %, "
                    f"{100 * ebm.get('heldout_near_first_error', nan):.1f} | {before:.4f} → {after:.4f} |")
    return "\n".join(rows)


def parse_coarse(text: str | None):
    """``"4,64"`` -> ``CoarseRanking(stride=4, keep=64)``; ``"full"`` -> None; None -> ``"preset"``."""
    from dmo_jax.config import CoarseRanking

    if text is None:
        return "preset"
    if text == "full":
        return None
    try:
        stride, keep = (int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--coarse must be STRIDE,KEEP (e.g. 4,64) or full, got {text!r}") from None
    if stride < 1 or keep < 1:
        raise ValueError(f"--coarse {text}: STRIDE and KEEP must be positive")
    return CoarseRanking(stride, keep)


def parse_sweep(text: str | None) -> tuple[str, list[int]] | None:
    """``"n=1,8,1000"`` -> ``("n", [1, 8, 1000])``; ``"R=1,5,10"`` -> ``("R", [1, 5, 10])``."""
    if text is None:
        return None
    name, _, values = text.partition("=")
    try:
        numbers = [int(v) for v in values.split(",") if v.strip()]
    except ValueError:
        numbers = []
    if name not in ("n", "R") or not numbers:
        raise ValueError(f"--sweep must look like n=1,8,1000 or R=1,5,10, got {text!r}")
    return name, numbers


def evaluate_main(argv: list[str] | None = None) -> None:
    from dmo_jax.config import VARIANTS
    from envs.cli import BACKEND_HELP, task_help
    from dmo_jax.inference import METHODS
    from dmo_jax.losses import NEGATIVE_MODES
    from envs.evaluation import WORLD_METHODS

    parser = argparse.ArgumentParser(
        description="Predict from each test scene's first image, execute the ranked candidates (falling back "
        "to the next when one is abandoned) and report success in the paper's layout.")
    _add_recipe_argument(parser, "the networks of that recipe (as given to bin/train_all)")
    parser.add_argument("--task", required=True, help=task_help())
    parser.add_argument("--method", required=True,
                        help=f"one of {', '.join(WORLD_METHODS + METHODS)}, or a comma-separated list (learned "
                        "methods then share one scoring of the bank); expert / blind / nearest (an oracle: the "
                        "training motion closest to the scene's recorded one) need no model, the others use "
                        "bin/train_all's networks")
    parser.add_argument("--n", type=int, default=8, help="candidates kept from the bank (default 8)")
    parser.add_argument("--R", type=int, default=1, help="DMO refinements at prediction (default 1)")
    parser.add_argument("--episodes", type=int,
                        help="test episodes per task (default: the first 100, or the whole split if shorter)")
    parser.add_argument("--backend", default="auto", choices=("auto", "mujoco", "mjx"), help=BACKEND_HELP)
    _add_preset_argument(parser)
    parser.add_argument("--workdir", default="runs", help="bin/train_all's work directory (default ./runs)")
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--variant", default="concat", choices=VARIANTS,
                        help="architecture (paper Table 2): concat = the paper's model (default)")
    parser.add_argument("--negatives", default="in-data+vae", choices=NEGATIVE_MODES, help="which EBM to use")
    parser.add_argument("--dmo-train-steps", type=int,
                        help="use the DMO trained with this many unrolled steps (Ours-5: 5, Ours-1: 1; "
                        "default the preset's)")
    _add_set_argument(parser, "the networks trained with these settings, as given to bin/train_all (checkpoints "
                      "refuse other values)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the methods' random draws (default 0)")
    parser.add_argument("--sweep", help="n=1,8,1000 or R=1,5,10: one row per value (paper Tables 5 and 6)")
    parser.add_argument("--coarse", metavar="STRIDE,KEEP|full",
                        help="how the bank is scored: in two stages (dmo_jax.config.CoarseRanking), every motion on "
                        "every STRIDE-th pose, then the KEEP best on all poses, e.g. 4,64; or full, every motion on "
                        "all poses (default: the preset's, cpu 4,64 and paper full)")
    parser.add_argument("--coarse-recall", action="store_true",
                        help="also score the bank in full, untimed, and report how many of its top n the coarse "
                        "scoring kept (coarse_recall)")
    parser.add_argument("--json", help="write the results and settings as JSON to this file")
    parser.add_argument("--save-viz", metavar="DIR", help="per episode (the first 10): a trajectories figure (PNG) and a rollout video (MP4)")
    args = parser.parse_args(argv)

    from envs.cli import check_output_file, check_seed, check_writable_dir, default_data_dir, positive, task_names

    methods = [m.strip() for m in args.method.split(",") if m.strip()]
    unknown = [m for m in methods if m not in WORLD_METHODS + METHODS]
    if not methods or unknown or len(set(methods)) != len(methods):
        _fail(f"--method {args.method!r}: expected distinct names from {', '.join(WORLD_METHODS + METHODS)}"
              + (f"; unknown: {', '.join(unknown)}" if unknown else ""))
    learned = [m for m in methods if m not in WORLD_METHODS]
    if args.episodes is not None:
        positive("--episodes", args.episodes)
    check_seed("--seed", args.seed)
    positive("--n", args.n)
    if args.R < 0:
        _fail(f"--R must be >= 0, got {args.R}")
    if args.dmo_train_steps is not None:
        positive("--dmo-train-steps", args.dmo_train_steps)
    try:
        sweep, coarse = parse_sweep(args.sweep), parse_coarse(args.coarse)
    except ValueError as err:
        _fail(str(err))
    if (args.coarse or args.coarse_recall) and not learned:
        _fail(f"--{'coarse' if args.coarse else 'coarse-recall'} needs a learned method (it is about how the EBM "
              "scores the bank)")
    if sweep and len(learned) < len(methods):
        _fail(f"--sweep needs learned methods only, not {', '.join(m for m in methods if m not in learned)}")
    if sweep and (min(sweep[1]) < (1 if sweep[0] == "n" else 0)):
        _fail(f"--sweep {args.sweep}: values must be >= {1 if sweep[0] == 'n' else 0}")
    names = task_names(args.task)
    if args.json:
        check_output_file(args.json, "--json")
    if args.save_viz:
        viz = Path(args.save_viz)
        if viz.exists():
            check_writable_dir(viz, f"--save-viz directory {viz}")
        else:  # created when the first picture is written
            check_writable_dir(viz.resolve().parent, f"directory {viz.resolve().parent} (for --save-viz {viz})")

    from dmo_jax import training
    from dmo_jax.comparison import row_label
    from dmo_jax.config import get_preset
    from dmo_jax.evaluation import evaluate_methods
    from envs import evaluation
    from envs.dataset import DatasetError
    from envs.platform import enable_compilation_cache

    enable_compilation_cache()
    try:
        preset = get_preset(args.preset, args.variant, args.recipe).with_overrides(args.set)
    except ValueError as err:
        _fail(str(err))
    data = args.data or default_data_dir(preset.image_size)
    settings = [(args.n, args.R)]
    if sweep:
        settings = [(v, args.R) if sweep[0] == "n" else (args.n, v) for v in sweep[1]]
    by_row = {}  # row label ("dmo n=8 R=1") -> {task: result}, rows in the order they appear
    for name in names:
        try:
            found = [evaluation.evaluate_world_method(name, m, args.episodes, data, args.backend)
                     for m in methods if m in WORLD_METHODS]
            if learned:
                found += evaluate_methods(
                    name, learned, preset=preset, workdir=args.workdir, data_root=data, settings=settings,
                    episodes=args.episodes, backend=args.backend, negatives=args.negatives,
                    dmo_train_iters=args.dmo_train_steps, seed=args.seed, viz_dir=args.save_viz, coarse=coarse,
                    measure_recall=args.coarse_recall)
        except (DatasetError, training.TrainingError, ValueError) as err:
            _fail(str(err))
        for result in found:
            label = row_label(result, {"dmo_train_steps": args.dmo_train_steps, "recipe": preset.recipe,
                                       "variant": preset.variant, "negatives": args.negatives,
                                       "dmo_inputs": preset.train.dmo_inputs, "set": args.set})
            by_row.setdefault(label, {})[name] = result
            print(f"{name} {label}: {result['successes']}/{result['episodes']} = {result['success_rate']:.0%} "
                  f"(execution {result['seconds']:.1f} s"
                  + (f", prediction {result['predict_seconds']:.1f} s; first-ranked motion "
                     f"{100 * result['first_error_m']:.1f} cm from the demonstration ("
                     f"{100 * result['first_depth_error_m']:.1f} cm in depth"
                     + (f"; its lowest point {100 * result['first_lowest_offset_m']:+.1f} cm above the "
                        "demonstration's" if "first_lowest_offset_m" in result else "")
                     + f"), EBM's top bank motion "
                     f"{100 * result['start_error_m']:.1f} cm, optimised motion ranked first in "
                     f"{result['optimised_first']:.0%} of scenes" + (
                         f"; the top {result['n']} lie {100 * result['mean_start_error_m']:.1f} cm from it, the "
                         f"optimised ones {100 * result['mean_optimised_error_m']:.1f} cm"
                         if "mean_optimised_error_m" in result else "")
                     + (f"; the coarse scoring kept {result['coarse_recall']:.0%} of the full one's top "
                        f"{result['n']} in {result['bank_seconds']:.1f} s, against {result['full_bank_seconds']:.1f} s"
                        if "coarse_recall" in result else "") + ")"
                     if "predict_seconds" in result else ")"),
                  file=sys.stderr)
    rows = [(label, {t: r["success_rate"] for t, r in per_task.items()}) for label, per_task in by_row.items()]
    results = [r for per_task in by_row.values() for r in per_task.values()]
    print(evaluation.success_table(rows))
    if args.save_viz:
        from dmo_jax.visualize import success_chart
        from envs.camera import write_png

        write_png(Path(args.save_viz) / "success.png", success_chart(dict(rows)))
    if args.json:
        episodes, successes = sum(r["episodes"] for r in results), sum(r["successes"] for r in results)
        method = methods[0] if len(methods) == 1 else methods
        _write_json(args.json, {
            # totals over every row (one task, method and setting: that row's numbers)
            "task": names[0] if len(names) == 1 else names, "method": method, "episodes": episodes,
            "successes": successes, "success_rate": successes / episodes,
            "settings": {"method": method, "preset": preset.name, "variant": preset.variant,
                         "recipe": preset.recipe, "dmo_inputs": preset.train.dmo_inputs, "negatives": args.negatives,
                         "dmo_train_steps": args.dmo_train_steps,
                         "episodes": args.episodes, "backend": args.backend, "data": data,
                         "workdir": args.workdir, "seed": args.seed, "sweep": args.sweep, "set": args.set,
                         "coarse": args.coarse},
            "results": results})


def cost_main(argv: list[str] | None = None) -> None:
    """``bin/cost``: paper Table 3 (EBM parameters and GMac per variant) from XLA's cost analysis."""

    parser = argparse.ArgumentParser(
        description="Paper Table 3 (EBM parameters and GMac, per variant) from XLA's cost analysis.")
    _add_preset_argument(parser)
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object {variant: {params_m, gmac_all, gmac_reuse}}")
    args = parser.parse_args(argv)
    from dmo_jax.cost import cost_table, format_table

    table = cost_table(args.preset)
    print(json.dumps(table) if args.json else format_table(args.preset, table))


BENCHMARK_SECTIONS = ("encoder", "train-step", "execution", "predict", "data")
#: Sections run only when asked for (``--only``).
EXTRA_SECTIONS = ("device",)


def benchmark_main(argv: list[str] | None = None) -> None:
    """``bin/benchmark``: the speed measurements of BENCHMARKS.md."""
    from dmo_jax.config import PRESETS
    from envs.cli import check_output_file, positive

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
                result[section] = _benchmark_section_in_subprocess(section, args)
            except RuntimeError as err:
                if args.out and result:  # keep the sections already measured
                    _write_json(args.out, result)
                _fail(f"{err}{f'; the sections before it are in {args.out}' if args.out and result else ''}")
        text = lambda r: "\n\n".join(_format_benchmark(s, r[s]) for s in BENCHMARK_SECTIONS)  # noqa: E731
    else:
        result = _benchmark_section(args.only, args)
        text = functools.partial(_format_benchmark, args.only)
    print(json.dumps(result, indent=1) if args.json else text(result))
    if args.out:
        _write_json(args.out, result)


def _benchmark_section(section: str, args) -> dict:
    """One section's measurements, plus this process's peak resident memory (``peak_rss_mb``)."""
    import resource

    from dmo_jax import benchmark

    if section == "encoder":
        result = benchmark.encoder_benchmark(args.preset or "paper", args.repeats, with_torch=args.torch_reference)
    elif section == "train-step":
        result = benchmark.training_step_benchmark(args.preset or "cpu", args.repeats)
    elif section == "predict":
        result = benchmark.predict_benchmark(args.preset or "cpu", repeats=args.repeats)
    elif section == "execution":
        from envs.benchmark import benchmark_execution

        result = {"rows": benchmark_execution(args.episodes, min(args.repeats, 3))}
    elif section == "device":
        result = benchmark.device_benchmark(repeats=args.repeats)
    else:
        from envs.benchmark import benchmark_data_generation

        result = benchmark_data_generation(episodes=args.episodes)
    # ru_maxrss is in KiB on Linux
    return {**result, "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def _benchmark_section_in_subprocess(section: str, args) -> dict:
    import os
    import subprocess

    root = Path(__file__).resolve().parents[1]
    argv = ["--only", section, "--json", "--repeats", str(args.repeats), "--episodes", str(args.episodes)]
    argv += (["--preset", args.preset] if args.preset else []) + (["--torch-reference"] if args.torch_reference else [])
    print(f"[benchmark] {section} ...", file=sys.stderr)
    t0 = time.perf_counter()
    code = "from envs.platform import setup; setup(); from dmo_jax.cli import benchmark_main; benchmark_main()"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, "-c", code, *argv], cwd=root, env=env, stdout=subprocess.PIPE, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark section {section!r} failed (exit status {proc.returncode}); rerun it alone "
                           f"with bin/benchmark --only {section}")
    print(f"[benchmark] {section} done in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return json.loads(proc.stdout)


def _format_benchmark(section: str, result: dict) -> str:
    from dmo_jax import benchmark

    if section == "encoder":
        text = benchmark.format_encoder_benchmark(result)
    elif section == "train-step":
        text = benchmark.format_training_step_benchmark(result)
    elif section == "predict":
        text = benchmark.format_predict_benchmark(result)
    elif section == "execution":
        text = "execution\n" + "\n".join(json.dumps(r) for r in result["rows"])
    elif section == "device":
        text = benchmark.format_device_benchmark(result)
    else:
        text = (f"data generation: {result['episodes']} episodes of {result['task']} at {result['image_size']}px in "
                f"{result['seconds']:.1f} s = {result['episodes_per_s']:.2f} episodes/s")
    return f"{text}\npeak resident memory of the process: {result['peak_rss_mb']:.0f} MB"


def ebm_misses_main(argv: list[str] | None = None) -> None:
    """``bin/ebm_misses``: the EBM's held-out top-1, every miss with its winner and distance."""
    from envs.cli import task_help

    parser = argparse.ArgumentParser(description="Explain the EBM's held-out misses (bin/train_all's ranking).")
    _add_recipe_argument(parser, "the EBM of that recipe (as given to bin/train_all)")
    parser.add_argument("--task", required=True, help=task_help(many=False))
    _add_preset_argument(parser)
    parser.add_argument("--workdir", default="runs", help="bin/train_all's work directory (default ./runs)")
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    _add_set_argument(parser, "the EBM trained with these settings, as given to bin/train_all")
    args = parser.parse_args(argv)

    from envs.cli import default_data_dir, task_names

    names = task_names(args.task)
    if len(names) != 1:
        _fail(f"--task takes one task name, got {args.task!r}")

    from dmo_jax.config import get_preset
    from dmo_jax.evaluation import ebm_heldout_misses
    from dmo_jax.training import TrainingError
    from envs.dataset import DatasetError
    from envs.platform import enable_compilation_cache

    enable_compilation_cache()
    try:
        preset = get_preset(args.preset, recipe=args.recipe).with_overrides(args.set)
        result = ebm_heldout_misses(names[0], preset=preset, workdir=args.workdir,
                                    data_root=args.data or default_data_dir(preset.image_size))
    except (DatasetError, TrainingError, ValueError) as err:
        _fail(str(err))
    print(json.dumps(result, indent=1))
    distances = sorted(m["distance_m"] for m in result["misses"])
    if distances:
        print(f"top-1 {result['top1']:.0%}; {len(distances)} misses, won by "
              f"{sorted({m['winner'] for m in result['misses']})}; winner-positive distance "
              f"{distances[0]:.3f}-{distances[-1]:.3f} m, median {distances[len(distances) // 2]:.3f} m",
              file=sys.stderr)
    near = [sum(d < cm / 100 for d in result["nearest_in_data_m"]) / result["episodes"] for cm in (1, 2)]
    print(f"another scene's motion lies within 1 / 2 cm of the positive in {near[0]:.0%} / {near[1]:.0%} "
          "of the episodes", file=sys.stderr)


def compare_main(argv: list[str] | None = None) -> None:
    """``bin/compare``: one success table from several ``bin/evaluate --json`` files, and one row
    against the others scene by scene."""
    parser = argparse.ArgumentParser(
        description="Merge bin/evaluate --json files into one success table and compare one row against every "
        "other scene by scene (the scenes only one of the two solves, with an exact sign test).")
    parser.add_argument("files", nargs="+", help="bin/evaluate --json files of the same networks and test scenes")
    parser.add_argument("--against",
                        help="the row compared with the others, as the table labels it (default: the first "
                        "'dmo n=8 R=1' row, e.g. 'dmo n=8 R=1 [bank]')")
    parser.add_argument("--rows", help="only these rows, comma-separated, in this order (default: every row, in the "
                        "order the files give them), e.g. 'dmo n=8 R=1,langevin n=8,gd n=8'")
    parser.add_argument("--alpha", type=float, default=0.05, help="significance level of the sign test (default 0.05)")
    args = parser.parse_args(argv)
    if not 0 < args.alpha < 1:
        _fail(f"--alpha must lie between 0 and 1, got {args.alpha}")

    from dmo_jax.comparison import comparison_report, distance_table, load_distances, load_evaluations, select_rows

    try:
        rows = load_evaluations(args.files)
        if args.rows:
            rows = select_rows(rows, [label.strip() for label in args.rows.split(",") if label.strip()])
        against = args.against or next((label for label in rows if label.startswith("dmo n=8 R=1")), "dmo n=8 R=1")
        print(comparison_report(rows, against, args.alpha))
        distances = {label: d for label, d in load_distances(args.files).items() if label in rows}
        if distances:
            print("\n" + distance_table(distances))
    except ValueError as err:
        _fail(str(err))
