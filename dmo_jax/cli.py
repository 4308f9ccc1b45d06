"""Library functions behind the method's commands (``bin/train_all``, ``bin/evaluate``)."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _fail(message: str) -> None:
    from envs.cli import fail

    fail(message)


def _write_json(path: str, payload) -> None:
    tmp = Path(path + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2))
    tmp.replace(path)


def train_all_main(argv: list[str] | None = None) -> None:
    from dmo_jax.config import DEFAULT_PRESET, PRESETS, VARIANTS
    from dmo_jax.losses import NEGATIVE_MODES

    parser = argparse.ArgumentParser(
        description="Per task: generate the data if missing, then train VAE -> EBM -> DMO, skipping what is "
        "trained and resuming what was interrupted.")
    parser.add_argument("--tasks", default="all", help="'all' or a comma-separated list of task names")
    parser.add_argument("--preset", default=DEFAULT_PRESET, choices=tuple(PRESETS))
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--workdir", default="runs", help="checkpoints and metrics (default ./runs)")
    parser.add_argument("--variant", default="concat", choices=VARIANTS)
    parser.add_argument("--negatives", default="in-data+vae", choices=NEGATIVE_MODES)
    parser.add_argument("--dmo-steps", type=int, help="R, DMO iterations unrolled in training (default: preset's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", help="also write the summary as JSON to this file")
    args = parser.parse_args(argv)
    if args.dmo_steps is not None and args.dmo_steps < 1:
        _fail(f"--dmo-steps must be at least 1, got {args.dmo_steps}")

    from envs.cli import task_names, default_data_dir
    from envs.dataset import DatasetError
    from dmo_jax import training, workflow
    from dmo_jax.config import get_preset

    preset = get_preset(args.preset, args.variant)
    names = task_names(args.tasks)
    data = args.data or default_data_dir(preset.image_size)
    training.maybe_initialize_distributed()
    summaries, start = {}, time.perf_counter()
    for name in names:
        print(f"[{name}] preset {preset.name}, variant {preset.variant}, negatives {args.negatives}", file=sys.stderr)
        try:
            summaries[name] = workflow.train_task(name, preset, data, args.workdir, args.negatives, args.dmo_steps,
                                                  args.seed, log=lambda m: print(m, file=sys.stderr))
        except (DatasetError, training.TrainingError) as err:
            _fail(str(err))
    print(_summary_table(summaries))
    print(f"total wall time {time.perf_counter() - start:.0f} s")
    if args.json:
        _write_json(args.json, summaries)


def _summary_table(summaries: dict) -> str:
    rows = ["| task | VAE s | EBM s | DMO s | EBM held-out top-1 | DMO position error before → after (m) |",
            "|---|---|---|---|---|---|"]
    for name, s in summaries.items():
        dmo = s["dmo"]
        before, after = dmo.get("heldout_position_before", float("nan")), dmo.get("heldout_position_after", float("nan"))
        rows.append(f"| {name} | {s['vae']['seconds']:.0f} | {s['ebm']['seconds']:.0f} | {dmo['seconds']:.0f} | "
                    f"{100 * s['ebm'].get('heldout_top1', float('nan')):.1f} % | {before:.4f} → {after:.4f} |")
    return "\n".join(rows)


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
    from dmo_jax.config import DEFAULT_PRESET, PRESETS, VARIANTS
    from dmo_jax.inference import METHODS
    from dmo_jax.losses import NEGATIVE_MODES
    from envs.evaluation import WORLD_METHODS

    parser = argparse.ArgumentParser(
        description="Predict from each test scene's first image, execute the ranked candidates (falling back "
        "to the next when one is abandoned) and report success in the paper's layout.")
    parser.add_argument("--task", required=True, help="a task name, a comma-separated list, or 'all'")
    parser.add_argument("--method", required=True, choices=WORLD_METHODS + METHODS,
                        help="expert / blind need no model; the others use bin/train_all's networks")
    parser.add_argument("--n", type=int, default=8, help="candidates kept from the bank (default 8)")
    parser.add_argument("--R", type=int, default=1, help="DMO refinements at prediction (default 1)")
    parser.add_argument("--episodes", type=int, default=100, help="test episodes per task (default 100)")
    parser.add_argument("--backend", default="auto", choices=("auto", "mujoco", "mjx"))
    parser.add_argument("--preset", default=DEFAULT_PRESET, choices=tuple(PRESETS))
    parser.add_argument("--workdir", default="runs", help="bin/train_all's work directory (default ./runs)")
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--variant", default="concat", choices=VARIANTS)
    parser.add_argument("--negatives", default="in-data+vae", choices=NEGATIVE_MODES, help="which EBM to use")
    parser.add_argument("--dmo-train-steps", type=int,
                        help="use the DMO trained with this many unrolled steps (Ours-5: 5, Ours-1: 1; "
                        "default the preset's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sweep", help="n=1,8,1000 or R=1,5,10: one row per value (paper Tables 5 and 6)")
    parser.add_argument("--json", help="write the results and settings as JSON to this file")
    parser.add_argument("--save-viz", metavar="DIR", help="per episode: trajectories PNG and rollout GIF")
    args = parser.parse_args(argv)

    from envs.cli import default_data_dir, positive, task_names

    positive("--episodes", args.episodes)
    positive("--n", args.n)
    if args.R < 0:
        _fail(f"--R must be >= 0, got {args.R}")
    if args.dmo_train_steps is not None:
        positive("--dmo-train-steps", args.dmo_train_steps)
    try:
        sweep = parse_sweep(args.sweep)
    except ValueError as err:
        _fail(str(err))
    if sweep and args.method in WORLD_METHODS:
        _fail(f"--sweep needs a learned method, not {args.method!r}")
    if sweep and (min(sweep[1]) < (1 if sweep[0] == "n" else 0)):
        _fail(f"--sweep {args.sweep}: values must be >= {1 if sweep[0] == 'n' else 0}")
    names = task_names(args.task)
    for path in filter(None, (args.json, args.save_viz)):
        parent = Path(path).resolve().parent
        if not parent.is_dir():
            _fail(f"directory {parent} (for {path}) does not exist")

    from dmo_jax import training
    from dmo_jax.config import get_preset
    from dmo_jax.evaluation import evaluate_method
    from envs import evaluation
    from envs.dataset import DatasetError

    preset = get_preset(args.preset, args.variant)
    data = args.data or default_data_dir(preset.image_size)
    settings = [dict(n=args.n, R=args.R)]
    if sweep:
        settings = [{"n": args.n, "R": args.R, sweep[0]: v} for v in sweep[1]]
    rows, results = [], []
    for setting in settings:
        rates = {}
        for name in names:
            try:
                if args.method in WORLD_METHODS:
                    result = evaluation.evaluate_world_method(name, args.method, args.episodes, data, args.backend)
                else:
                    result = evaluate_method(
                        name, args.method, preset=preset, workdir=args.workdir, data_root=data,
                        episodes=args.episodes, backend=args.backend, negatives=args.negatives,
                        dmo_train_iters=args.dmo_train_steps, seed=args.seed, viz_dir=args.save_viz, **setting)
            except (DatasetError, training.TrainingError, ValueError) as err:
                _fail(str(err))
            results.append(result)
            rates[name] = result["success_rate"]
            print(f"{name} {args.method} {_setting_label(args.method, setting)}: {result['successes']}/"
                  f"{result['episodes']} = {rates[name]:.0%} (execution {result['seconds']:.1f} s"
                  + (f", prediction {result['predict_seconds']:.1f} s)" if "predict_seconds" in result else ")"),
                  file=sys.stderr)
        rows.append((f"{args.method} {_setting_label(args.method, setting)}".strip(), rates))
    print(evaluation.success_table(rows))
    if args.json:
        _write_json(args.json, {
            "settings": {"method": args.method, "preset": preset.name, "variant": preset.variant,
                         "negatives": args.negatives, "dmo_train_steps": args.dmo_train_steps,
                         "episodes": args.episodes, "backend": args.backend, "data": data,
                         "workdir": args.workdir, "seed": args.seed, "sweep": args.sweep},
            "results": results})


def _setting_label(method: str, setting: dict) -> str:
    from envs.evaluation import WORLD_METHODS

    if method in WORLD_METHODS:
        return ""
    return f"n={setting['n']}" + (f" R={setting['R']}" if method == "dmo" else "")
