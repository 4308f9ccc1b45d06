"""``bin/compare``: one success table from several ``bin/evaluate --json`` files, and one row against
the others scene by scene."""
from __future__ import annotations

import argparse

from dmo_jax.commands.common import fail
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

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
        fail(f"--alpha must lie between 0 and 1, got {args.alpha}")

    from dmo_jax.comparison import (choice_table, comparison_report, distance_table, load_choices, load_distances,
                                    load_evaluations, precision_table, select_rows)

    try:
        rows = load_evaluations(args.files)
        if args.rows:
            rows = select_rows(rows, [label.strip() for label in args.rows.split(",") if label.strip()])
        against = args.against or next((label for label in rows if label.startswith("dmo n=8 R=1")), "dmo n=8 R=1")
        print(comparison_report(rows, against, args.alpha))
        distances = {label: d for label, d in load_distances(args.files).items() if label in rows}
        if distances:
            print("\n" + distance_table(distances))
        choices = {label: c for label, c in load_choices(args.files).items() if label in rows}
        if choices:
            print("\n" + choice_table(choices))
            precision = precision_table(choices)
            if precision:
                print("\n" + precision)
    except ValueError as err:
        fail(str(err))
