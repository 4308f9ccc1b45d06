"""Pictures of predictions (``bin/evaluate --save-viz``): candidate trajectories drawn on the
input image with matplotlib, and a video of the executed rollout."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from envs.motion import UV, denormalize_uv

#: Candidate paths are coloured by energy rank with this colour map: rank 1 (lowest energy)
#: blue, then green, yellow, up to red.
CMAP = "turbo"


def _check_overlay_args(rgb: np.ndarray, candidates: np.ndarray, chosen: int, top: int, energies, pixels: int):
    """One-line ValueErrors for what :func:`trajectory_overlay` cannot draw."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or rgb.shape[0] != rgb.shape[1] or not rgb.size:
        raise ValueError(f"trajectory_overlay expects a square uint8 image [S, S, 3], got {rgb.dtype} {rgb.shape}")
    if candidates.ndim != 3 or candidates.shape[2] < 2 or len(candidates) == 0:
        raise ValueError(f"trajectory_overlay expects candidates [K, T, 11] with K >= 1, got shape {candidates.shape}")
    if not 0 <= chosen < len(candidates):
        raise ValueError(f"trajectory_overlay: chosen must index one of the {len(candidates)} candidates, got {chosen}")
    if top < 1:
        raise ValueError(f"trajectory_overlay: top must be at least 1, got {top}")
    if energies is not None and np.shape(energies) != (len(candidates),):
        raise ValueError(f"trajectory_overlay expects energies [K] = [{len(candidates)}], "
                         f"got shape {np.shape(energies)}")
    if pixels < 256:
        raise ValueError(f"trajectory_overlay: pixels must be at least 256, got {pixels}")


def trajectory_overlay(rgb: np.ndarray, candidates: np.ndarray, chosen: int = 0, top: int = 8,
                       energies: np.ndarray | None = None, title: str = "", success: bool | None = None,
                       pixels: int = 512) -> np.ndarray:
    """A ``[pixels, pixels, 3]`` uint8 figure: the scene ``rgb [S, S, 3]`` with the projected
    paths of the first ``top`` of the ranked ``candidates [K, T, 11]`` (lowest energy first)
    coloured by energy rank (colour bar; ``energies [K]``, if given, label its ticks), and the
    executed one (``chosen``) drawn white with a black edge, a circle at its start and a cross at
    its end. ``title`` heads the figure, followed by the outcome when ``success`` is given
    (green for success, red for failure)."""
    rgb, candidates = np.asarray(rgb), np.asarray(candidates)
    _check_overlay_args(rgb, candidates, chosen, top, energies, pixels)
    from matplotlib import patheffects
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import BoundaryNorm
    from matplotlib.lines import Line2D

    from envs.video import agg_figure, figure_rgb

    s = rgb.shape[0]
    top = min(top, len(candidates))
    paths = np.asarray(denormalize_uv(candidates[:, :, UV], s))  # [K, T, 2] pixel (column, row)

    fig = agg_figure(pixels, pixels)
    fig.set_layout_engine("constrained")
    ax = fig.add_subplot()
    ax.imshow(rgb, interpolation="nearest")
    ax.set_xlim(-0.5, s - 0.5)
    ax.set_ylim(s - 0.5, -0.5)
    ax.set_xticks([])
    ax.set_yticks([])

    norm = BoundaryNorm(np.arange(0.5, top + 1.5), 256)
    mappable = ScalarMappable(norm=norm, cmap=CMAP)
    for k in reversed(range(top)):  # the best candidate drawn last, on top
        if k != chosen:
            ax.plot(*paths[k].T, color=mappable.to_rgba(k + 1), linewidth=1.6, alpha=0.9)
    outline = [patheffects.Stroke(linewidth=4.5, foreground="black"), patheffects.Normal()]
    ax.plot(*paths[chosen].T, color="white", linewidth=2.5, path_effects=outline)
    ax.plot(*paths[chosen, 0], marker="o", markersize=7, color="white", markeredgecolor="black")
    ax.plot(*paths[chosen, -1], marker="X", markersize=9, color="white", markeredgecolor="black")
    ax.legend(handles=[Line2D([], [], color="white", linewidth=2.5, path_effects=outline,
                              label=f"executed (rank {chosen + 1})")],
              loc="lower left", fontsize="small", framealpha=0.7)

    bar = fig.colorbar(mappable, ax=ax, shrink=0.85, pad=0.02)
    ticks = np.unique(np.linspace(1, top, min(top, 8)).round().astype(int))
    bar.set_ticks(ticks)
    if energies is not None:
        bar.set_ticklabels([f"{t}  ({float(energies[t - 1]):.3g})" for t in ticks])
        bar.set_label("energy rank (energy); 1 = lowest")
    else:
        bar.set_label("energy rank; 1 = lowest")

    if success is not None:
        title = f"{title}: {'success' if success else 'failure'}" if title else ("success" if success else "failure")
    if title:
        colour = "black" if success is None else ("tab:green" if success else "tab:red")
        ax.set_title(title, color=colour, fontsize="medium", fontweight="bold")
    return figure_rgb(fig)


def save_episode_visuals(viz_dir, task_name: str, test, candidates: np.ndarray, energies: np.ndarray,
                         result: dict, preset, max_episodes: int = 10, label: str = "",
                         video: str = "mp4") -> None:
    """For the first ``max_episodes`` episodes write ``<task>[_<label>]_<i>_{ok,fail}.png`` (the
    trajectories, :func:`trajectory_overlay`) and ``.mp4`` (or ``.gif`` with ``video="gif"``:
    the executed candidate's rollout, native MuJoCo). ``candidates [E, K, 101, 11]`` and
    ``energies [E, K]`` are ranked, lowest energy first."""
    from envs import execution
    from envs.camera import write_png
    from envs.tasks import get_task
    from envs.video import render_rollout, write_gif, write_mp4

    if video not in ("mp4", "gif"):
        raise ValueError(f"save_episode_visuals: video must be 'mp4' or 'gif', got {video!r}")
    out = Path(viz_dir)
    out.mkdir(parents=True, exist_ok=True)
    task = get_task(task_name, test.meta["image_size"])
    for i in range(min(max_episodes, len(result["episode_success"]))):
        chosen = int(result["candidate_used"][i])
        ok = bool(result["episode_success"][i])
        stem = out / f"{task_name}{'_' + label if label else ''}_{i:03d}_{'ok' if ok else 'fail'}"
        title = f"{task_name}{' (' + label + ')' if label else ''}\nepisode {i}"
        write_png(stem.with_suffix(".png"), trajectory_overlay(
            np.asarray(test.rgb[i]), candidates[i], chosen, energies=np.asarray(energies[i]), title=title, success=ok))
        scenes = task.batch([task.reset(int(test.seeds[i]))])
        run = execution.execute(task.world, candidates[i, chosen][None], scenes, task.success, "mujoco")
        frames = render_rollout(task.world, scenes, run.qpos)
        if video == "mp4":
            write_mp4(stem.with_suffix(".mp4"), frames)
        else:
            write_gif(stem.with_suffix(".gif"), frames)


def success_chart(rows: dict[str, dict[str, float]], width: int = 900, height: int = 420) -> np.ndarray:
    """A bar chart ``uint8 [height, width, 3]`` of success per task (groups) and method (bars):
    ``rows`` maps a row label (``bin/evaluate``'s) to ``{task name: success rate in [0, 1]}``."""
    from envs.evaluation import ABBREVIATIONS, TASK_ORDER
    from envs.video import agg_figure, figure_rgb

    tasks = [t for t in TASK_ORDER if any(t in per_task for per_task in rows.values())]
    if not tasks:
        raise ValueError("success_chart needs at least one task's success rate")
    fig = agg_figure(width, height)
    ax = fig.add_subplot()
    bar = 0.8 / len(rows)
    for i, (label, per_task) in enumerate(rows.items()):
        x = [k + (i - (len(rows) - 1) / 2) * bar for k, t in enumerate(tasks) if t in per_task]
        ax.bar(x, [100 * per_task[t] for t in tasks if t in per_task], bar, label=label)
    ax.set_xticks(range(len(tasks)), [ABBREVIATIONS[t] for t in tasks])
    ax.set(ylabel="success (%)", ylim=(0, 100), title="success per task")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    fig.tight_layout()
    return figure_rgb(fig)
