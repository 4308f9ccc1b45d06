"""``bin/reproduce``: rebuild the paper's success tables (``dmo_jax.reproduce``) and render them into
BENCHMARKS.md."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dmo_jax.commands.common import add_preset_argument, add_recipe_argument, fail
from dmo_jax.config import VARIANTS
from dmo_jax.reproduce import TABLES, TITLES, render, reproduce, update_report
from envs.commands.common import BACKEND_HELP, default_data_dir, make_output_dir, positive, task_help, task_names
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    parser = argparse.ArgumentParser(
        description="Rebuild the paper's success tables: generate missing data, train what is not trained, "
        "evaluate, write results/table<N>.json and render the tables into BENCHMARKS.md. Resumable: what is "
        "recorded is skipped.")
    parser.add_argument("--tables", default=",".join(TABLES),
                        help=f"comma-separated, of {', '.join(TABLES)} (default all): " + "; ".join(
                            f"{t}: {TITLES[t].split(': ')[1]}" for t in TABLES))
    parser.add_argument("--tasks", default="all", help=task_help() + " (default all)")
    add_preset_argument(parser)
    add_recipe_argument(parser, "the networks of Tables 2, 4, 5 and 6 (Table 1 runs every recipe)")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help=f"Table 2's architectures, comma-separated, of {', '.join(VARIANTS)} (default all; on 2 "
                        "CPU cores vit trains about 20 times slower than concat)")
    parser.add_argument("--episodes", type=int, default=100, help="test scenes per task (default 100)")
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--workdir", default="runs", help="checkpoints (default ./runs)")
    parser.add_argument("--results", default="results", help="where the table files go (default ./results)")
    parser.add_argument("--report", default="BENCHMARKS.md",
                        help="the Markdown file the tables are rendered into (default ./BENCHMARKS.md)")
    parser.add_argument("--backend", default="auto", choices=("auto", "mujoco", "mjx"), help=BACKEND_HELP)
    parser.add_argument("--seed", type=int, default=0, help="training and prediction seed (default 0)")
    args = parser.parse_args(argv)
    tables = _comma_list(args.tables, TABLES, "--tables", "tables")
    variants = _comma_list(args.variants, VARIANTS, "--variants", "variants")
    positive("--episodes", args.episodes)

    from envs.dataset import DatasetError
    from envs.platform import enable_compilation_cache

    from dmo_jax import training
    from dmo_jax.config import get_preset

    enable_compilation_cache()
    try:
        preset = get_preset(args.preset, recipe=args.recipe)
    except ValueError as err:
        fail(str(err))
    names = task_names(args.tasks)
    data = args.data or default_data_dir(preset.image_size)
    for path, option in ((args.workdir, "--workdir"), (args.results, "--results"), (data, "--data")):
        make_output_dir(path, option)
    log = lambda m: print(m, file=sys.stderr)  # noqa: E731
    try:
        files = reproduce(tables, names, preset, args.episodes, results_dir=args.results, data=data,
                          workdir=args.workdir, variants=variants, backend=args.backend, seed=args.seed,
                          command=sys.argv[1:] if argv is None else argv, log=log)
    except (DatasetError, training.TrainingError, ValueError, OSError) as err:
        fail(str(err))
    sections = {t: render(path, t) for t, path in files.items()}
    update_report(Path(args.report), sections)
    for table, body in sections.items():
        print(f"\n{TITLES[table]}\n\n{body}")


def _comma_list(value: str, allowed, option: str, what: str) -> list[str]:
    """The comma-separated items of ``value``, each one of ``allowed``; a one-line error otherwise."""
    items = [v.strip() for v in value.split(",") if v.strip()]
    if not items or any(v not in allowed for v in items):
        fail(f"{option} {value!r}: expected comma-separated {what} of {', '.join(allowed)}")
    return items
