"""``bin/task_report``: the task-suite table of BENCHMARKS.md (expert and blind success, MJX/native
agreement)."""
from __future__ import annotations

import argparse
import sys

from envs.commands.common import default_data_dir, fail, positive, task_help, task_names
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    parser = argparse.ArgumentParser(
        description="The task-suite table of BENCHMARKS.md: expert and blind success on the native back-end "
        "and MJX/native agreement, from generated datasets.")
    parser.add_argument("--task", default="all", help=task_help() + " (default all)")
    parser.add_argument("--data", default=default_data_dir(256), help="dataset root directory (default ./data/256px)")
    parser.add_argument("--episodes", type=int,
                        help="test episodes per task (default: the first 100, or the whole split if shorter)")
    parser.add_argument("--mjx-episodes", type=int, default=20,
                        help="episodes per task run on MJX too, to compare verdicts with native MuJoCo (default 20)")
    args = parser.parse_args(argv)
    if args.episodes is not None:
        positive("--episodes", args.episodes)
    positive("--mjx-episodes", args.mjx_episodes)
    names = task_names(args.task)
    from envs.dataset import DatasetError
    from envs.evaluation import task_suite_report

    try:
        table = task_suite_report(args.data, names, args.episodes, args.mjx_episodes,
                                  log=lambda row: print(row, file=sys.stderr))
    except (DatasetError, ValueError) as err:
        fail(str(err))
    print(table)
