"""Pictures of predictions (``bin/evaluate --save-viz``): candidate trajectories drawn on the
input image, and a GIF of the executed rollout."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .motion import UV, denormalize_uv

SCALE = 4  # the network image is drawn 4x larger so thin trajectories stay visible


def _draw_polyline(canvas: np.ndarray, points: np.ndarray, colour, width: int = 1) -> None:
    """Draw ``points [T, 2]`` (x, y pixels) on ``canvas [H, W, 3]`` in place."""
    h, w, _ = canvas.shape
    for (x0, y0), (x1, y1) in zip(points[:-1], points[1:]):
        steps = int(max(abs(x1 - x0), abs(y1 - y0), 1)) * 2
        t = np.linspace(0.0, 1.0, steps + 1)
        xs, ys = np.rint(x0 + t * (x1 - x0)).astype(int), np.rint(y0 + t * (y1 - y0)).astype(int)
        for dx in range(-(width // 2), width - width // 2):
            for dy in range(-(width // 2), width - width // 2):
                ok = (xs + dx >= 0) & (xs + dx < w) & (ys + dy >= 0) & (ys + dy < h)
                canvas[ys[ok] + dy, xs[ok] + dx] = colour


def energy_colour(rank: float) -> tuple[int, int, int]:
    """Blue (lowest energy, rank 0) to red (highest, rank 1)."""
    return int(255 * rank), int(80 + 60 * (1 - abs(2 * rank - 1))), int(255 * (1 - rank))


def trajectory_overlay(rgb: np.ndarray, candidates: np.ndarray, chosen: int = 0, top: int = 8) -> np.ndarray:
    """``rgb [S, S, 3]`` uint8 and ranked ``candidates [K, 101, 11]`` -> a ``[4S, 4S, 3]`` picture
    of the first ``top`` candidates' projected paths, coloured by energy rank, the executed
    one (``chosen``) in white and thicker."""
    s = rgb.shape[0]
    canvas = np.repeat(np.repeat(rgb, SCALE, 0), SCALE, 1).copy()
    top = min(top, len(candidates))
    for k in reversed(range(top)):
        px = (np.asarray(denormalize_uv(candidates[k][:, UV], s)) + 0.5) * SCALE - 0.5
        if k == chosen:
            continue
        _draw_polyline(canvas, px, energy_colour(k / max(top - 1, 1)))
    px = (np.asarray(denormalize_uv(candidates[chosen][:, UV], s)) + 0.5) * SCALE - 0.5
    _draw_polyline(canvas, px, (255, 255, 255), width=3)
    return canvas


def save_episode_visuals(viz_dir, task_name: str, test, candidates: np.ndarray, energies: np.ndarray,
                         result: dict, preset, max_episodes: int = 10, label: str = "") -> None:
    """For the first ``max_episodes`` episodes write ``<task>[_<label>]_<i>_{ok,fail}.png`` (trajectories)
    and ``.gif`` (the executed candidate's rollout, native MuJoCo)."""
    from envs import execution
    from envs.camera import write_png
    from envs.tasks import get_task
    from envs.video import render_rollout, write_gif

    out = Path(viz_dir)
    out.mkdir(parents=True, exist_ok=True)
    task = get_task(task_name, test.meta["image_size"])
    for i in range(min(max_episodes, len(result["episode_success"]))):
        chosen = int(result["candidate_used"][i])
        stem = out / f"{task_name}{'_' + label if label else ''}_{i:03d}_{'ok' if result['episode_success'][i] else 'fail'}"
        write_png(stem.with_suffix(".png"), trajectory_overlay(np.asarray(test.rgb[i]), candidates[i], chosen))
        scenes = task.batch([task.reset(int(test.seeds[i]))])
        run = execution.execute(task.world, candidates[i, chosen][None], scenes, task.success, "mujoco")
        write_gif(stem.with_suffix(".gif"), render_rollout(task.world, scenes, run.qpos))
