"""``bin/render``: the front view (RGB beside depth) of the default scene, or a contact sheet of
tasks' first training scenes."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from envs.commands.common import check_output_file, check_seed, fail, image_size, task_help, task_names
from envs.platform import setup


def main(argv: list[str] | None = None) -> None:
    setup()  # the headless GL and XLA back-ends, before mujoco or jax are imported

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
            tiles.append(cam.rgb(task.reset(episode_seed(seed, "train", 0))))
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
