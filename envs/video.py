"""Rollout videos (render an executed episode frame by frame, write it as MP4 or GIF) and the
off-screen matplotlib figures that the pictures are drawn on.

Both video writers go through imageio: MP4 is H.264 from the ffmpeg binary that the
imageio-ffmpeg wheel ships (nothing is fetched at run time), GIF is Pillow's encoder (adaptive
palette, only the changed part of each frame stored). Both write atomically. Figures use
matplotlib's Agg back-end and never open a window.
"""
from __future__ import annotations

import copy
import warnings
from pathlib import Path

import mujoco
import numpy as np

from envs.camera import SceneRenderer, write_atomically
from envs.execution import SceneBatch, World


def _check_frames(frames: np.ndarray, writer: str) -> np.ndarray:
    """``frames`` as a uint8 ``[F, H, W, 3]`` array with F >= 1, or a one-line ValueError."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or 0 in frames.shape:
        raise ValueError(f"{writer} expects uint8 frames [F, H, W, 3] with F, H, W >= 1, "
                         f"got {frames.dtype} {frames.shape}")
    return frames


def write_gif(path: str | Path, frames: np.ndarray, frame_ms: int = 80) -> None:
    """Write uint8 ``frames [F, H, W, 3]`` as a looping animated GIF, ``frame_ms`` per frame,
    atomically."""
    frames = _check_frames(frames, "write_gif")
    if not frame_ms >= 10:
        raise ValueError(f"write_gif expects frame_ms >= 10 (GIF delays are in 10 ms steps), got {frame_ms}")
    import imageio.v3 as iio

    write_atomically(path, lambda tmp: iio.imwrite(tmp, frames, extension=".gif", plugin="pillow",
                                                   duration=int(frame_ms), loop=0, optimize=True))


def write_mp4(path: str | Path, frames: np.ndarray, fps: float = 12.5) -> None:
    """Write uint8 ``frames [F, H, W, 3]`` as an H.264 MP4 at ``fps`` frames per second,
    atomically. H.264 (4:2:0) needs even sides: an odd height or width gains one row or column
    repeating the last."""
    frames = _check_frames(frames, "write_mp4")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"write_mp4 expects a positive frame rate fps, got {fps}")
    _, h, w, _ = frames.shape
    if h % 2 or w % 2:
        frames = np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    import imageio.v3 as iio

    def write(tmp: Path) -> None:
        with warnings.catch_warnings():
            # ffmpeg runs as a child process (fork, then exec at once), which JAX's fork warning
            # does not tell apart from a fork that keeps running Python.
            warnings.filterwarnings("ignore", r"os\.fork\(\) was called", RuntimeWarning)
            iio.imwrite(tmp, frames, extension=".mp4", plugin="FFMPEG", fps=float(fps), codec="libx264",
                        pixelformat="yuv420p", quality=8, macro_block_size=1, ffmpeg_log_level="error")

    write_atomically(path, write)


def agg_figure(width: int, height: int, dpi: int = 100):
    """A matplotlib ``Figure`` of ``width`` x ``height`` pixels on an off-screen Agg canvas (no
    pyplot, so nothing global holds it)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if width < 1 or height < 1:
        raise ValueError(f"a figure needs a positive width and height in pixels, got {width} x {height}")
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def figure_rgb(fig) -> np.ndarray:
    """Draw ``fig`` (from :func:`agg_figure`) and return its pixels, uint8 ``[H, W, 3]``."""
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def render_rollout(world: World, scenes: SceneBatch, qpos: np.ndarray, episode: int = 0, size: int = 256,
                   every: int = 4) -> np.ndarray:
    """Front-camera RGB frames ``[F, size, size, 3]`` of episode ``episode`` of an executed
    batch: its initial state, then ``qpos [E, W, nq]`` after every ``every``-th waypoint."""
    model = copy.copy(scenes.model_for(world.model, episode))
    # Shadows are most of a frame's software rendering: a shadow map of twice the frame's side
    # instead of the scene's 2,048 looks the same (a mean difference of 0.1 in 255 at 256 px) and
    # renders a frame in 23 instead of 41 ms on 2 cores.
    model.vis.quality.shadowsize = min(model.vis.quality.shadowsize, 2 * size)
    data = mujoco.MjData(model)
    states = [scenes.qpos[episode]] + list(qpos[episode, every - 1::every])
    frames = []
    with SceneRenderer(model, size) as renderer:
        for q in states:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            frames.append(renderer.rgb(data))
    return np.stack(frames)
