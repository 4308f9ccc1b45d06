"""``bin/cost``: paper Table 3 (EBM parameters and GMac per variant) from XLA's cost analysis."""
from __future__ import annotations

import argparse
import json

from dmo_jax.commands.common import add_preset_argument
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    parser = argparse.ArgumentParser(
        description="Paper Table 3 (EBM parameters and GMac, per variant) from XLA's cost analysis.")
    add_preset_argument(parser)
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object {variant: {params_m, gmac_all, gmac_reuse}}")
    args = parser.parse_args(argv)
    from dmo_jax.cost import cost_table, format_table

    table = cost_table(args.preset)
    print(json.dumps(table) if args.json else format_table(args.preset, table))
