"""``bin/ebm_misses``: the EBM's held-out top-1, every miss with its winner and distance."""
from __future__ import annotations

import argparse
import json
import sys

from dmo_jax.commands.common import add_preset_argument, add_recipe_argument, add_set_argument, fail
from envs.commands.common import default_data_dir, task_help, task_names
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    parser = argparse.ArgumentParser(description="Explain the EBM's held-out misses (bin/train_all's ranking).")
    add_recipe_argument(parser, "the EBM of that recipe (as given to bin/train_all)")
    parser.add_argument("--task", required=True, help=task_help(many=False))
    add_preset_argument(parser)
    parser.add_argument("--workdir", default="runs", help="bin/train_all's work directory (default ./runs)")
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    add_set_argument(parser, "the EBM trained with these settings, as given to bin/train_all")
    args = parser.parse_args(argv)

    names = task_names(args.task)
    if len(names) != 1:
        fail(f"--task takes one task name, got {args.task!r}")

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
        fail(str(err))
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
