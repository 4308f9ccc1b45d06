"""``bin/train_all``: per task, generate the data if missing, then train VAE -> EBM -> DMO
(skipping what is trained, resuming what was interrupted)."""
from __future__ import annotations

import argparse
import sys
import time

from dmo_jax.commands.common import add_preset_argument, add_recipe_argument, add_set_argument, fail, write_json
from envs.commands.common import check_output_file, check_seed, default_data_dir, make_output_dir, task_help, task_names
from envs.platform import expose_cpu_cores_as_devices, setup


def main(argv: list[str] | None = None) -> None:
    if argv is None:  # this process is the command: data parallel over every core when there is no accelerator
        expose_cpu_cores_as_devices()
    setup()  # the headless GL and XLA back-ends; both before mujoco or jax are imported

    from dmo_jax.config import VARIANTS
    from dmo_jax.losses import NEGATIVE_MODES

    parser = argparse.ArgumentParser(
        description="Per task: generate the data if missing, then train VAE -> EBM -> DMO, skipping what is "
        "trained and resuming what was interrupted.")
    add_recipe_argument(parser)
    parser.add_argument("--tasks", default="all", help=task_help() + " (default all)")
    add_preset_argument(parser)
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--workdir", default="runs", help="checkpoints and metrics (default ./runs)")
    parser.add_argument("--variant", default="concat", choices=VARIANTS,
                        help="architecture (paper Table 2): concat = the paper's model (default)")
    parser.add_argument("--negatives", default="in-data+vae", choices=NEGATIVE_MODES,
                        help="the EBM's negatives (paper Table 4): in-data+vae (default) or only-vae")
    parser.add_argument("--dmo-train-steps", type=int,
                        help="R the DMO is trained with: refinements unrolled per training step (Ours-5: 5, Ours-1: "
                        "1; default the preset's train.dmo_train_steps); bin/evaluate picks that DMO with the same "
                        "option")
    add_set_argument(parser, "replace a setting of the preset; a run of more steps continues a finished one in "
                     "the same --workdir")
    parser.add_argument("--seed", type=int, default=0, help="training seed: initialisation, batches, draws (default 0)")
    parser.add_argument("--json", help="also write the summary as JSON to this file")
    args = parser.parse_args(argv)
    if args.dmo_train_steps is not None and args.dmo_train_steps < 1:
        fail(f"--dmo-train-steps must be at least 1, got {args.dmo_train_steps}")

    from envs.dataset import DatasetError, split_dir
    from dmo_jax import training, workflow
    from dmo_jax.config import get_preset
    from envs.platform import enable_compilation_cache

    check_seed("--seed", args.seed)
    enable_compilation_cache()
    try:
        preset = get_preset(args.preset, args.variant, args.recipe).with_overrides(args.set)
    except ValueError as err:
        fail(str(err))
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
        fail(str(err))
    summaries, start = {}, time.perf_counter()
    for name in names:
        print(f"[{name}] preset {preset.name}, recipe {preset.recipe}, variant {preset.variant}, "
              f"negatives {args.negatives}"
              + (f", {', '.join(args.set)}" if args.set else ""), file=sys.stderr)
        try:
            summaries[name] = workflow.train_task(name, preset, data, args.workdir, args.negatives, args.dmo_train_steps,
                                                  args.seed, log=lambda m: print(m, file=sys.stderr))
        except (DatasetError, training.TrainingError, ValueError, RuntimeError, OSError) as err:
            fail(f"{name}: {err}")
    print(_summary_table(summaries))
    print(f"total wall time {time.perf_counter() - start:.0f} s")
    if args.json:
        write_json(args.json, summaries)


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
    for name, s in summaries.items():
        if "selection" in s:
            sel = s["selection"]
            rows.append(f"{name}: selection head on {sel['scenes']} training scenes (fitted on them): the lowest "
                        f"energy succeeds in {100 * sel['lowest_energy_succeeds']:.1f} %, the head's choice in "
                        f"{100 * sel['selected_succeeds']:.1f} % ({sel['seconds']:.0f} s)")
    return "\n".join(rows)
