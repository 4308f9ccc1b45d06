"""Library functions behind ``bin/render`` and ``bin/execute``."""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def render_main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Render the front view (RGB beside depth) of the default scene.")
    parser.add_argument("--out", required=True, help="PNG file to write")
    parser.add_argument("--size", type=int, default=256, help="image width = height in pixels (default 256)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if not out.parent.is_dir():
        _fail(f"output directory {out.parent} does not exist")
    import mujoco

    from envs import camera, demo

    world = demo.default_world(args.size)
    data = mujoco.MjData(world.model)
    data.qpos[:] = world.home_qpos()
    mujoco.mj_forward(world.model, data)
    try:
        with camera.SceneRenderer(world.model, args.size) as renderer:
            rgb, depth = renderer.rgbd(data)
    except (ValueError, RuntimeError) as err:
        _fail(str(err))
    camera.write_png(out, np.concatenate([rgb, camera.depth_to_rgb(depth)], axis=1))
    print(f"wrote {out} ({args.size}x{args.size} RGB | depth {depth.min():.2f}-{depth.max():.2f} m)")


def execute_main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description="Execute a motion ([101, 11] camera-frame poses, .npy) in the default scene "
        "(Panda, table, cube) and print the per-waypoint outcome. Without --motion, runs the "
        "built-in scripted pick-up of the cube."
    )
    parser.add_argument("--motion", help=".npy file with a [101, 11] float motion")
    parser.add_argument("--backend", default="auto", choices=("auto", "mujoco", "mjx"))
    parser.add_argument("--save-motion", help="also write the executed motion to this .npy file")
    parser.add_argument("--json", help="write the outcome as JSON to this file")
    args = parser.parse_args(argv)

    from envs import demo, execution

    world = demo.default_world()
    if args.motion:
        try:
            motion = np.load(args.motion, allow_pickle=False)
        except (OSError, ValueError) as err:
            _fail(f"cannot read motion file {args.motion}: {err}")
    else:
        motion = demo.pick_cube_motion(world)
    if args.save_motion:
        tmp = Path(args.save_motion + ".tmp.npy")
        np.save(tmp, motion)
        tmp.replace(args.save_motion)
    try:
        result = execution.execute(world, motion, world.default_scenes(1), demo.cube_lifted(world), args.backend)
    except ValueError as err:
        _fail(str(err))
    cube = world.model.joint("cube_free").qposadr[0]
    print("waypoint  ik  valid  cube_xyz               success")
    for w in range(result.qpos.shape[1]):
        xyz = result.qpos[0, w, cube : cube + 3]
        print(f"{w:8d}  {'ok' if result.reached[0, w] else '--':>2}  {'yes' if result.valid[0, w] else 'no':>5}  "
              f"{xyz[0]:6.3f} {xyz[1]:6.3f} {xyz[2]:6.3f}   {'yes' if result.success_after[0, w] else ''}")
    verdict = {
        "success": bool(result.success[0]),
        "failed_waypoints": int((~result.reached[0]).sum()),
        "abandoned": bool(result.abandoned[0]),
    }
    print(json.dumps(verdict))
    if args.json:
        tmp = Path(args.json + ".tmp")
        tmp.write_text(json.dumps(verdict, indent=2))
        tmp.replace(args.json)


def _task_names(arg: str) -> list[str]:
    from envs.evaluation import TASK_ORDER
    from envs.tasks import TASKS

    names = [t for t in TASK_ORDER if t in TASKS] if arg == "all" else arg.split(",")
    unknown = [n for n in names if n not in TASKS]
    if unknown:
        _fail(f"unknown task {unknown[0]!r}; expected 'all' or a comma-separated list of: {', '.join(TASKS)}")
    return names


def _positive(name: str, value: int) -> None:
    if value < 1:
        _fail(f"{name} must be a positive integer, got {value}")


def generate_data_main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Generate expert demonstrations (train and test splits) for tasks.")
    parser.add_argument("--task", required=True, help="a task name, a comma-separated list, or 'all'")
    parser.add_argument("--train", type=int, default=1000, help="training episodes (default 1000)")
    parser.add_argument("--test", type=int, default=100, help="test episodes (default 100)")
    parser.add_argument("--out", default="data", help="dataset root directory (default ./data)")
    parser.add_argument("--seed", type=int, default=0, help="base seed; train and test seeds never overlap")
    parser.add_argument("--image-size", type=int, default=256, help="image width = height (default 256)")
    parser.add_argument("--workers", type=int, default=None, help="physics threads (default: one per core)")
    args = parser.parse_args(argv)
    for name in ("train", "test", "image_size"):
        _positive(f"--{name.replace('_', '-')}", getattr(args, name))
    if args.seed < 0:
        _fail(f"--seed must be non-negative, got {args.seed}")
    names = _task_names(args.task)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        _fail(f"cannot create output directory {out}: {err}")
    if not os.access(out, os.W_OK):
        _fail(f"output directory {out} is not writable")

    import time

    from envs.dataset import generate_split, load_split
    from envs.tasks import get_task

    for name in names:
        task = get_task(name, args.image_size)
        start = time.perf_counter()
        for split, n in (("train", args.train), ("test", args.test)):
            generate_split(task, split, n, out, base_seed=args.seed, workers=args.workers)
        meta = load_split(out, name, "train").meta
        print(f"{name}: {args.train} train + {args.test} test episodes at {args.image_size}px in "
              f"{time.perf_counter() - start:.1f} s (expert success {meta['expert_success_rate']:.1%}) -> {out / name}")


def evaluate_main(argv: list[str] | None = None) -> None:
    from envs.evaluation import WORLD_METHODS

    parser = argparse.ArgumentParser(description="Execute a method's motions on the test scenes and report success.")
    parser.add_argument("--task", required=True, help="a task name, a comma-separated list, or 'all'")
    parser.add_argument("--method", required=True, choices=WORLD_METHODS)
    parser.add_argument("--episodes", type=int, default=100, help="test episodes per task (default 100)")
    parser.add_argument("--data", default="data", help="dataset root directory (default ./data)")
    parser.add_argument("--backend", default="auto", choices=("auto", "mujoco", "mjx"))
    parser.add_argument("--json", help="write the results as JSON to this file")
    args = parser.parse_args(argv)
    _positive("--episodes", args.episodes)
    names = _task_names(args.task)
    if args.json and not Path(args.json).resolve().parent.is_dir():
        _fail(f"directory of --json {args.json} does not exist")

    import time

    from envs import evaluation
    from envs.dataset import DatasetError, load_split
    from envs.tasks import get_task

    results, rates = [], {}
    for name in names:
        try:
            test = load_split(args.data, name, "test")
            train = load_split(args.data, name, "train") if args.method == "blind" else None
        except DatasetError as err:
            _fail(str(err))
        episodes = min(args.episodes, len(test))
        task = get_task(name, test.meta["image_size"])
        scenes = [task.reset(int(s)) for s in test.seeds[:episodes]]
        start = time.perf_counter()
        out = evaluation.execute_candidates(
            task, scenes, evaluation.world_method_candidates(args.method, test, train, episodes), args.backend)
        seconds = time.perf_counter() - start
        successes = int(out["success"].sum())
        rates[name] = successes / episodes
        results.append({
            "task": name, "method": args.method, "episodes": episodes, "successes": successes,
            "success_rate": rates[name], "seconds": round(seconds, 2),
            "episode_success": out["success"].astype(int).tolist(),
        })
        print(f"{name}: {successes}/{episodes} = {rates[name]:.0%} ({seconds:.1f} s)", file=sys.stderr)
    print(evaluation.success_table(rates, args.method))
    if args.json:
        payload = results[0] if len(results) == 1 else {"results": results}
        payload = {**payload, "settings": {"backend": args.backend, "data": args.data}}
        tmp = Path(args.json + ".tmp")
        tmp.write_text(json.dumps(payload, indent=2))
        tmp.replace(args.json)
