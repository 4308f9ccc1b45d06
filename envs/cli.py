"""Library functions behind ``bin/render`` and ``bin/execute``."""
from __future__ import annotations

import argparse
import json
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
