"""Library functions behind the simulator's commands (``bin/render``, ``bin/execute``,
``bin/generate_data``, ``bin/task_report``)."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


#: What ``bin/generate_data`` writes unless told: the default preset's (``cpu``) image size, so the
#: commands that train and evaluate it find the data where they look.
DEFAULT_IMAGE_SIZE = 64


def default_data_dir(image_size: int) -> str:
    """Datasets of different image sizes live side by side: ``data/<size>px``."""
    return f"data/{image_size}px"


def fail(message: str) -> None:
    """Print ``error: <message>`` as one line on stderr and exit with status 2."""
    text = " ".join(line.strip() for line in str(message).splitlines() if line.strip())
    print(f"error: {text}", file=sys.stderr)
    raise SystemExit(2)


def write_json(path: str | Path, payload) -> None:
    """Write ``payload`` as indented JSON to ``path`` atomically."""
    from envs.dataset import atomic_write_text

    atomic_write_text(Path(path), json.dumps(payload, indent=2))


def check_writable_dir(path: str | Path, label: str | None = None) -> Path:
    """Fail unless ``path`` is an existing directory this process can create files in (tried
    for real: permission bits say nothing for root or on read-only file systems). ``label``
    names the directory in the message (default ``output directory <path>``)."""
    import tempfile

    path = Path(path)
    label = label or f"output directory {path}"
    if not path.exists():
        fail(f"{label} does not exist")
    if not path.is_dir():
        fail(f"{label} is not a directory")
    try:
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as err:
        fail(f"{label} is not writable ({err.strerror or err}); expected a directory you can write to")
    return path


def check_output_file(path: str | Path, option: str) -> Path:
    """Fail unless the file ``path`` (given with ``option``) can be written: not a directory,
    inside an existing writable directory."""
    path = Path(path)
    if path.is_dir():
        fail(f"{option} {path} is a directory; expected a file name")
    check_writable_dir(path.resolve().parent, f"directory {path.resolve().parent} (for {option} {path})")
    return path


def make_output_dir(path: str | Path, option: str) -> Path:
    """Create the directory ``path`` (given with ``option``) with its parents if needed; fail
    unless that works and the directory is writable."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        fail(f"cannot create {option} directory {path}: {err.strerror or err}")
    return check_writable_dir(path, f"{option} directory {path}")


def image_size(name: str, value: int) -> None:
    """Fail unless ``value`` is an image side the offscreen renderer supports."""
    from envs.panda import MAX_IMAGE_SIZE

    if not 1 <= value <= MAX_IMAGE_SIZE:
        fail(f"{name} must be between 1 and {MAX_IMAGE_SIZE} pixels, got {value}")


#: Seeds are 31-bit: JAX keys, NumPy generators and the episodes' seed layout all take them.
MAX_SEED = 2**31 - 1


def check_seed(name: str, value: int) -> None:
    if not 0 <= value <= MAX_SEED:
        fail(f"{name} must be an integer in [0, {MAX_SEED}], got {value}")


def render_main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description="Render the front view (RGB beside depth) of the default scene, or with --task a "
        "contact sheet of each task's first training scene, labelled with the task names.")
    parser.add_argument("--out", required=True, help="PNG file to write")
    parser.add_argument("--size", type=int, default=256, help="image width = height in pixels (default 256)")
    parser.add_argument("--task", help=task_help() + ": a contact sheet (RGB)")
    parser.add_argument("--seed", type=int, default=0, help="base seed of the scenes (with --task)")
    args = parser.parse_args(argv)
    image_size("--size", args.size)
    check_seed("--seed", args.seed)
    names = task_names(args.task) if args.task else None
    out = Path(args.out)
    check_output_file(out, "--out")
    from envs import camera

    try:
        if names:
            image = _contact_sheet(names, args.size, args.seed)
            what = f"contact sheet of {args.task}"
        else:
            image, (near, far) = _front_view(args.size)
            what = f"RGB | depth, colour bar {near:.2f}-{far:.2f} m: the 1st-99th percentile of the scene's depths"
    except (ValueError, RuntimeError) as err:
        fail(str(err))
    camera.write_png(out, image)
    print(f"wrote {out} ({what})")


def _front_view(size: int) -> tuple[np.ndarray, tuple[float, float]]:
    """The default scene at home from the front camera, drawn with matplotlib: RGB beside depth
    in a colour map with a colour bar in metres, uint8 ``[H, W, 3]``; and the depth range
    ``(near, far)`` in metres that the colour map spans."""
    import mujoco

    from envs import camera, demo
    from envs.video import agg_figure, figure_rgb

    world = demo.default_world(size)
    data = mujoco.MjData(world.model)
    data.qpos[:] = world.home_qpos()
    mujoco.mj_forward(world.model, data)
    with camera.SceneRenderer(world.model, size) as renderer:
        rgb, depth = renderer.rgbd(data)
    far_plane = float(world.model.vis.map.zfar * world.model.stat.extent)
    near, far = _depth_range(depth, far_plane)
    cell = max(size, 256)
    fig = agg_figure(2 * cell + 90, cell + 30)
    left = fig.add_axes((0.0, 0.0, cell / (2 * cell + 90), cell / (cell + 30)))
    right = fig.add_axes((cell / (2 * cell + 90), 0.0, cell / (2 * cell + 90), cell / (cell + 30)))
    left.imshow(rgb, interpolation="nearest")
    shown = right.imshow(np.clip(depth, near, far), cmap="viridis", vmin=near, vmax=far, interpolation="nearest")
    for ax, title in ((left, "RGB"), (right, "depth")):
        ax.set_axis_off()
        ax.set_title(title, fontsize=10)
    bar = fig.colorbar(shown, cax=fig.add_axes(((2 * cell + 8) / (2 * cell + 90), 0.05, 14 / (2 * cell + 90), 0.85)))
    bar.set_label("depth (m)", fontsize=9)
    bar.ax.tick_params(labelsize=8)
    return figure_rgb(fig), (near, far)


def _depth_range(depth: np.ndarray, far_plane: float,
                 percentiles: tuple[float, float] = (1, 99)) -> tuple[float, float]:
    """The ``percentiles`` of the finite depths ``[H, W]`` (m) nearer than the far plane (where
    the empty background renders), so a legend spans what the scene holds; the whole finite
    range if nothing is nearer."""
    finite = depth[np.isfinite(depth)]
    scene = finite[finite < 0.999 * far_plane]
    if scene.size == 0:
        scene = finite if finite.size else np.zeros(1, np.float32)
    near, far = (float(v) for v in np.percentile(scene, percentiles))
    return near, max(far, near + 1e-3)


def _contact_sheet(names: list[str], size: int, seed: int, columns: int = 3) -> np.ndarray:
    """Each task's first training scene (RGB) on a grid of ``columns``, the task name above each
    tile, drawn with matplotlib: uint8 ``[rows * (C + L), columns * C, 3]`` with tiles of C =
    ``size`` times the smallest whole factor that makes them at least 256 pixels wide (so the
    names fit) and a label band of L pixels."""
    from envs.dataset import episode_seed
    from envs.tasks import get_task
    from envs.tasks.base import TaskCamera
    from envs.video import agg_figure, figure_rgb

    tiles = []
    for name in names:
        task = get_task(name, size)
        with TaskCamera(task) as cam:
            tiles.append(cam.rgbd(task.reset(episode_seed(seed, "train", 0)))[0])
    columns = min(columns, len(tiles))
    rows = -(-len(tiles) // columns)
    cell = size * -(-256 // size)
    label = 22
    width, height = columns * cell, rows * (cell + label)
    fig = agg_figure(width, height)
    for i, (name, tile) in enumerate(zip(names, tiles)):
        r, c = divmod(i, columns)
        bottom = height - (r + 1) * (cell + label)
        ax = fig.add_axes((c * cell / width, bottom / height, cell / width, cell / height))
        ax.imshow(tile, interpolation="nearest")
        ax.set_axis_off()
        fig.text((c + 0.5) * cell / width, (bottom + cell + label / 2) / height, name,
                 ha="center", va="center", fontsize=9)
    return figure_rgb(fig)


def execute_main(argv: list[str] | None = None) -> None:
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


BACKEND_HELP = "physics back-end: native MuJoCo, MJX, or auto (MJX on an accelerator, else native; default)"


def task_help(many: bool = True) -> str:
    """``--task``'s help: the task names (and, with ``many``, lists and 'all')."""
    from envs.tasks import TASKS

    names = ", ".join(TASKS)
    return f"a task name ({names}), a comma-separated list, or 'all'" if many else f"one task name ({names})"


def task_names(arg: str) -> list[str]:
    from envs.evaluation import TASK_ORDER
    from envs.tasks import TASKS

    names = [t for t in TASK_ORDER if t in TASKS] if arg == "all" else arg.split(",")
    unknown = [n for n in names if n not in TASKS]
    if unknown:
        fail(f"unknown task {unknown[0]!r}; expected 'all' or a comma-separated list of: {', '.join(TASKS)}")
    return names


def positive(name: str, value: int) -> None:
    if value < 1:
        fail(f"{name} must be a positive integer, got {value}")


def generate_data_main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Generate expert demonstrations (train and test splits) for tasks.")
    parser.add_argument("--task", required=True, help=task_help())
    parser.add_argument("--train", type=int, default=1000, help="training episodes (default 1000)")
    parser.add_argument("--test", type=int, default=100, help="test episodes (default 100)")
    parser.add_argument("--out", help="dataset root directory (default ./data/<image-size>px)")
    parser.add_argument("--seed", type=int, default=0, help="base seed; train and test seeds never overlap")
    parser.add_argument("--image-size", type=int, default=DEFAULT_IMAGE_SIZE,
                        help=f"image width = height (default {DEFAULT_IMAGE_SIZE}, the default preset's; the paper's is 256)")
    parser.add_argument("--workers", type=int, default=None, help="physics threads (default: one per core)")
    args = parser.parse_args(argv)
    for name in ("train", "test"):
        positive(f"--{name}", getattr(args, name))
    image_size("--image-size", args.image_size)
    check_seed("--seed", args.seed)
    if args.workers is not None:
        positive("--workers", args.workers)
    names = task_names(args.task)
    import time

    from envs.dataset import DatasetError, generate_split, load_split, size_in_name
    from envs.tasks import get_task

    named = size_in_name(args.out) if args.out else None
    if named is not None and named != args.image_size:
        fail(f"--out {args.out} is named for {named}px images but --image-size is {args.image_size}; "
             f"pass --image-size {named} or another --out")
    out = make_output_dir(args.out or default_data_dir(args.image_size), "--out")

    for name in names:
        task = get_task(name, args.image_size)
        start = time.perf_counter()
        try:
            for split, n in (("train", args.train), ("test", args.test)):
                generate_split(task, split, n, out, base_seed=args.seed, workers=args.workers)
            meta = load_split(out, name, "train").meta
        except (DatasetError, ValueError, RuntimeError, OSError) as err:
            fail(f"{name}: {err}")
        print(f"{name}: {args.train} train + {args.test} test episodes at {args.image_size}px in "
              f"{time.perf_counter() - start:.1f} s (expert success {meta['expert_success_rate']:.1%}) -> {out / name}")


def task_report_main(argv: list[str] | None = None) -> None:
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
