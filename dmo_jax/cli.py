"""Library functions behind the method's commands (``bin/train_all``)."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


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
        tmp = Path(args.json + ".tmp")
        tmp.write_text(json.dumps(summaries, indent=2))
        tmp.replace(args.json)


def _summary_table(summaries: dict) -> str:
    rows = ["| task | VAE s | EBM s | DMO s | EBM held-out top-1 | DMO position error before → after (m) |",
            "|---|---|---|---|---|---|"]
    for name, s in summaries.items():
        dmo = s["dmo"]
        before, after = dmo.get("heldout_position_before", float("nan")), dmo.get("heldout_position_after", float("nan"))
        rows.append(f"| {name} | {s['vae']['seconds']:.0f} | {s['ebm']['seconds']:.0f} | {dmo['seconds']:.0f} | "
                    f"{100 * s['ebm'].get('heldout_top1', float('nan')):.1f} % | {before:.4f} → {after:.4f} |")
    return "\n".join(rows)
