"""``bin/evaluate``: predict from each test scene's first image, execute the ranked candidates and
report success in the paper's layout."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dmo_jax.commands.common import (add_preset_argument, add_recipe_argument, add_set_argument, fail, parse_coarse,
                                     parse_sweep, write_json)
from envs.commands.common import (BACKEND_HELP, check_output_file, check_seed, check_writable_dir, default_data_dir,
                                  positive, task_help, task_names)
from envs.platform import expose_cpu_cores_as_devices, setup


def main(argv: list[str] | None = None) -> None:
    if argv is None:  # this process is the command: each core ranks its share of the images, the same results
        expose_cpu_cores_as_devices()
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    from dmo_jax.config import VARIANTS
    from dmo_jax.inference import METHODS
    from dmo_jax.losses import NEGATIVE_MODES
    from envs.evaluation import WORLD_METHODS

    parser = argparse.ArgumentParser(
        description="Predict from each test scene's first image, execute the ranked candidates (falling back "
        "to the next when one is abandoned) and report success in the paper's layout.")
    add_recipe_argument(parser, "the networks of that recipe (as given to bin/train_all)")
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
    add_preset_argument(parser)
    parser.add_argument("--workdir", default="runs", help="bin/train_all's work directory (default ./runs)")
    parser.add_argument("--data", help="dataset root (default ./data/<preset image size>px)")
    parser.add_argument("--variant", default="concat", choices=VARIANTS,
                        help="architecture (paper Table 2): concat = the paper's model (default)")
    parser.add_argument("--negatives", default="in-data+vae", choices=NEGATIVE_MODES, help="which EBM to use")
    parser.add_argument("--dmo-train-steps", type=int,
                        help="use the DMO trained with this many unrolled steps (Ours-5: 5, Ours-1: 1; "
                        "default the preset's)")
    add_set_argument(parser, "the networks trained with these settings, as given to bin/train_all (checkpoints "
                     "refuse other values)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the methods' random draws (default 0)")
    parser.add_argument("--sweep", help="n=1,8,1000 or R=1,5,10: one row per value (paper Tables 5 and 6)")
    parser.add_argument("--coarse", metavar="STRIDE,KEEP|full",
                        help="how the bank is scored: in two stages (dmo_jax.config.CoarseRanking), every motion on "
                        "every STRIDE-th pose, then the KEEP best on all poses, e.g. 6,64; or full, every motion on "
                        "all poses (default: the preset's, cpu 6,32 and paper full)")
    parser.add_argument("--coarse-recall", action="store_true",
                        help="also score the bank in full, untimed, and report how many of its top n the coarse "
                        "scoring kept (coarse_recall)")
    parser.add_argument("--each-candidate", action="store_true",
                        help="also execute every ranked candidate alone (K times the execution) and report how many "
                        "scenes some candidate solves, and how often a start and an optimised motion succeed "
                        "(with --json: the success of each, for other selection rules)")
    parser.add_argument("--show-preset", action="store_true",
                        help="print the resolved preset (--preset, --recipe, --variant, --set) and, per task, where "
                        "the preset each network's checkpoint recorded differs from it; evaluate nothing")
    parser.add_argument("--json", help="write the results and settings as JSON to this file")
    parser.add_argument("--save-viz", metavar="DIR", help="per episode (the first 10): a trajectories figure (PNG) and a rollout video (MP4)")
    args = parser.parse_args(argv)

    methods = [m.strip() for m in args.method.split(",") if m.strip()]
    unknown = [m for m in methods if m not in WORLD_METHODS + METHODS]
    if not methods or unknown or len(set(methods)) != len(methods):
        fail(f"--method {args.method!r}: expected distinct names from {', '.join(WORLD_METHODS + METHODS)}"
             + (f"; unknown: {', '.join(unknown)}" if unknown else ""))
    learned = [m for m in methods if m not in WORLD_METHODS]
    if args.episodes is not None:
        positive("--episodes", args.episodes)
    check_seed("--seed", args.seed)
    positive("--n", args.n)
    if args.R < 0:
        fail(f"--R must be >= 0, got {args.R}")
    if args.dmo_train_steps is not None:
        positive("--dmo-train-steps", args.dmo_train_steps)
    try:
        sweep, coarse = parse_sweep(args.sweep), parse_coarse(args.coarse)
    except ValueError as err:
        fail(str(err))
    if args.show_preset and not learned:
        fail("--show-preset needs a learned method (the others use no networks)")
    if args.each_candidate and not learned:
        fail("--each-candidate needs a learned method (the others execute one motion per scene)")
    if (args.coarse or args.coarse_recall) and not learned:
        fail(f"--{'coarse' if args.coarse else 'coarse-recall'} needs a learned method (it is about how the EBM "
             "scores the bank)")
    if sweep and len(learned) < len(methods):
        fail(f"--sweep needs learned methods only, not {', '.join(m for m in methods if m not in learned)}")
    if sweep and (min(sweep[1]) < (1 if sweep[0] == "n" else 0)):
        fail(f"--sweep {args.sweep}: values must be >= {1 if sweep[0] == 'n' else 0}")
    names = task_names(args.task)
    if args.json:
        check_output_file(args.json, "--json")
    if args.save_viz:
        viz = Path(args.save_viz)
        if viz.exists():
            check_writable_dir(viz, f"--save-viz directory {viz}")
        else:  # created when the first picture is written
            check_writable_dir(viz.resolve().parent, f"directory {viz.resolve().parent} (for --save-viz {viz})")

    from dmo_jax import selection, training
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
        fail(str(err))
    if args.show_preset:
        import json

        from dmo_jax.config import preset_record
        from dmo_jax.workflow import describe_networks

        print(json.dumps(preset_record(preset), indent=2))
        for name in names:
            try:
                print(f"[{name}]\n" + describe_networks(args.workdir, name, preset, learned, args.negatives,
                                                         args.dmo_train_steps))
            except ValueError as err:
                fail(str(err))
        return
    data = args.data or default_data_dir(preset.image_size)
    settings = [(args.n, args.R)]
    if sweep:
        settings = [(v, args.R) if sweep[0] == "n" else (args.n, v) for v in sweep[1]]
    networks = {"variant": preset.variant, "recipe": preset.recipe, "dmo_inputs": preset.train.dmo_inputs,
                "depth_cue": preset.head.depth_cue, "negatives": args.negatives,
                "ebm_mined_steps": training.mined_steps(preset.train, args.negatives),
                "dmo_train_steps": args.dmo_train_steps, "image_size": preset.image_size,
                "selection_scenes": preset.train.selection_scenes, "selection_phases": selection.PHASES,
                "set": args.set}  # what the rows are named by
    by_row = {}  # row label ("dmo n=8 R=1") -> {task: result}, rows in the order they appear
    for name in names:
        try:
            found = [evaluation.evaluate_world_method(name, m, args.episodes, data, args.backend)
                     for m in methods if m in WORLD_METHODS]
            if learned:
                found += evaluate_methods(
                    name, learned, preset=preset, workdir=args.workdir, data_root=data, settings=settings,
                    episodes=args.episodes, backend=args.backend, negatives=args.negatives,
                    dmo_train_steps=args.dmo_train_steps, seed=args.seed, viz_dir=args.save_viz, coarse=coarse,
                    measure_recall=args.coarse_recall, each_candidate=args.each_candidate)
        except (DatasetError, training.TrainingError, ValueError) as err:
            fail(str(err))
        for result in found:
            label = row_label(result, networks)
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
                        if "coarse_recall" in result else "")
                     + (f"; executed alone, a start succeeds in {result['start_success_rate']:.0%} of cases"
                        + (f", an optimised motion in {result['optimised_success_rate']:.0%}"
                           if "optimised_success_rate" in result else "")
                        + f", and some candidate solves {result['some_candidate_solves']:.0%} of the scenes "
                        f"(some start {result['some_start_solves']:.0%}, the one nearest the demonstration "
                        f"{result['nearest_candidate_solves']:.0%})" if "some_candidate_solves" in result else "")
                     + ")"
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
        write_json(args.json, {
            # totals over every row (one task, method and setting: that row's numbers)
            "task": names[0] if len(names) == 1 else names, "method": method, "episodes": episodes,
            "successes": successes, "success_rate": successes / episodes,
            "settings": {"method": method, "preset": preset.name, **networks,
                         "episodes": args.episodes, "backend": args.backend, "data": data,
                         "workdir": args.workdir, "seed": args.seed, "sweep": args.sweep, "coarse": args.coarse},
            "results": results})
