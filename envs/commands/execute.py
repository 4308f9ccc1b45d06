"""``bin/execute``: execute a motion file, or the scripted pick-up, in the default scene and print
the per-waypoint outcome."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from envs.commands.common import BACKEND_HELP, check_output_file, fail, write_json
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

    parser = argparse.ArgumentParser(
        description="Execute a motion ([101, 11] camera-frame poses, .npy) in the default scene "
        "(Panda, table, cube) and print the per-waypoint outcome. Without --motion, runs the "
        "built-in scripted pick-up of the cube."
    )
    parser.add_argument("--motion", help=".npy file with a [101, 11] float motion")
    parser.add_argument("--backend", default="auto", choices=("auto", "mujoco", "mjx"), help=BACKEND_HELP)
    parser.add_argument("--save-motion", help="also write the executed motion to this .npy file")
    parser.add_argument("--json", help="write the outcome as JSON to this file")
    args = parser.parse_args(argv)
    for path, what in ((args.save_motion, "--save-motion"), (args.json, "--json")):
        if path:
            check_output_file(path, what)
    motion = load_motion_file(args.motion) if args.motion else None

    from envs import demo, execution

    world = demo.default_world()
    if motion is None:
        motion = demo.pick_cube_motion(world)
    if args.save_motion:
        from envs.dataset import atomic_save

        atomic_save(Path(args.save_motion), motion)
    try:
        result = execution.execute(world, motion, world.default_scenes(1), demo.cube_lifted(world), args.backend)
    except ValueError as err:
        fail(str(err))
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
        write_json(args.json, verdict)


def load_motion_file(path: str) -> np.ndarray:
    """The ``[101, 11]`` float32 motion stored in the ``.npy`` file ``path``; fails (exit 2) with
    one line if the file is missing, unreadable, not one array, or not a finite motion."""
    from envs.motion import check_motions

    try:
        with open(path, "rb") as f:
            magic = f.read(6)
        if magic != b"\x93NUMPY" and not magic.startswith(b"PK"):
            fail(f"motion file {path} is not a NumPy file; expected a .npy file written with numpy.save")
        motion = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        detail = "it holds Python objects, not numbers" if "pickle" in str(err) else str(err)
        fail(f"cannot read motion file {path}: {detail}; expected a .npy file written with numpy.save")
    if not isinstance(motion, np.ndarray):
        motion.close()
        fail(f"motion file {path} holds several arrays (.npz); expected one [101, 11] array (.npy)")
    try:
        return check_motions(motion, f"the motion in {path}", single=True)
    except ValueError as err:
        fail(str(err))

