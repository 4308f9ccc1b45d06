"""Media output through imageio and matplotlib: what the writers produce reads back with the
same libraries (frame count, size, pixels); the pictures have their size and content."""
import types

import imageio.v3 as iio
import numpy as np
import pytest

from dmo_jax import visualize
from envs import camera, video
from envs.commands import render


def _blocks(frames: int, h: int, w: int) -> np.ndarray:
    """uint8 ``[F, H, W, 3]``: a few flat colours, a square moving right by a pixel a frame."""
    out = np.zeros((frames, h, w, 3), np.uint8)
    out[..., 2] = 200
    out[:, h // 2:, :, 1] = 150
    for f in range(frames):
        out[f, 2:8, 2 + f:8 + f] = (250, 40, 40)
    return out


def test_png_reads_back_exactly_and_leaves_no_temporary_file(tmp_path):
    img = np.random.default_rng(1).integers(0, 256, (9, 13, 3), dtype=np.uint8)
    out = tmp_path / "a.png"
    camera.write_png(out, img)
    np.testing.assert_array_equal(iio.imread(out), img)
    camera.write_png(out, img[::-1])  # replaces the file
    np.testing.assert_array_equal(iio.imread(out), img[::-1])
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]


def test_a_failed_write_keeps_the_old_file_and_removes_the_temporary_one(tmp_path):
    out = tmp_path / "a.png"
    out.write_bytes(b"old")

    def broken(tmp):
        tmp.write_bytes(b"part")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        camera.write_atomically(out, broken)
    assert out.read_bytes() == b"old" and [p.name for p in tmp_path.iterdir()] == ["a.png"]


def test_gif_reads_back_with_its_frames_size_and_timing(tmp_path):
    frames = _blocks(4, 12, 20)
    out = tmp_path / "a.gif"
    video.write_gif(out, frames, frame_ms=50)
    back = iio.imread(out, index=None, plugin="pillow")
    assert back.shape[:3] == (4, 12, 20)
    np.testing.assert_array_equal(back[..., :3], frames)  # few colours: the palette holds them all
    meta = iio.immeta(out, index=0, plugin="pillow")
    assert meta["duration"] == 50 and meta["loop"] == 0
    assert [p.name for p in tmp_path.iterdir()] == ["a.gif"]


def test_mp4_reads_back_with_its_frames_and_size(tmp_path):
    frames = _blocks(5, 16, 24)
    out = tmp_path / "a.mp4"
    video.write_mp4(out, frames, fps=10)
    back = iio.imread(out, index=None, plugin="FFMPEG")
    assert back.shape == (5, 16, 24, 3)
    assert np.abs(back.astype(int) - frames).mean() < 12  # lossy, but the same picture
    assert iio.immeta(out, plugin="FFMPEG")["fps"] == pytest.approx(10)
    assert [p.name for p in tmp_path.iterdir()] == ["a.mp4"]


def test_mp4_pads_odd_sides_to_even(tmp_path):
    out = tmp_path / "odd.mp4"
    video.write_mp4(out, _blocks(2, 15, 21))
    assert iio.imread(out, index=None, plugin="FFMPEG").shape == (2, 16, 22, 3)


@pytest.mark.parametrize("writer", [video.write_gif, video.write_mp4])
@pytest.mark.parametrize("frames", [np.zeros((2, 8, 8, 3), np.float32), np.zeros((8, 8, 3), np.uint8),
                                    np.zeros((0, 8, 8, 3), np.uint8), np.zeros((2, 8, 8, 4), np.uint8)])
def test_video_writers_reject_what_is_not_rgb_frames(tmp_path, writer, frames):
    with pytest.raises(ValueError, match=r"uint8 frames \[F, H, W, 3\]"):
        writer(tmp_path / "x", frames)
    assert list(tmp_path.iterdir()) == []


def test_video_writers_reject_bad_timing(tmp_path):
    with pytest.raises(ValueError, match="frame_ms >= 10"):
        video.write_gif(tmp_path / "x.gif", _blocks(2, 8, 8), frame_ms=0)
    with pytest.raises(ValueError, match="positive frame rate"):
        video.write_mp4(tmp_path / "x.mp4", _blocks(2, 8, 8), fps=0)


def _line_candidates(k: int = 5) -> np.ndarray:
    """``[k, 101, 11]`` candidates whose paths are horizontal lines at different heights."""
    cands = np.zeros((k, 101, 11), np.float32)
    cands[:, :, 0] = np.linspace(-0.8, 0.8, 101)
    cands[:, :, 1] = np.linspace(-0.6, 0.6, k)[:, None]
    return cands


def test_trajectory_overlay_is_a_figure_of_the_requested_size_with_the_paths():
    rgb = np.full((32, 32, 3), 90, np.uint8)
    picture = visualize.trajectory_overlay(rgb, _line_candidates(), chosen=2, energies=np.arange(5.0),
                                           title="reach_target", success=False, pixels=300)
    assert picture.shape == (300, 300, 3) and picture.dtype == np.uint8
    colours = np.unique(picture.reshape(-1, 3), axis=0)
    assert len(colours) > 50  # image, paths, colour bar, text: not blank
    assert (picture == 255).all(-1).sum() > 200  # the executed path is white
    assert (picture == 90).all(-1).sum() > 0.2 * 300 * 300  # the scene fills much of it
    assert visualize.trajectory_overlay(rgb, _line_candidates(), pixels=256).shape == (256, 256, 3)


@pytest.mark.parametrize("kwargs, message", [
    (dict(rgb=np.zeros((32, 32), np.uint8)), r"square uint8 image \[S, S, 3\]"),
    (dict(candidates=np.zeros((0, 101, 11), np.float32)), r"candidates \[K, T, 11\] with K >= 1"),
    (dict(chosen=5), "chosen must index one of the 5 candidates, got 5"),
    (dict(top=0), "top must be at least 1"),
    (dict(energies=np.zeros(3)), r"energies \[K\] = \[5\], got shape \(3,\)"),
    (dict(pixels=100), "pixels must be at least 256"),
])
def test_trajectory_overlay_rejects_bad_input(kwargs, message):
    args = dict(rgb=np.zeros((32, 32, 3), np.uint8), candidates=_line_candidates()) | kwargs
    with pytest.raises(ValueError, match=message):
        visualize.trajectory_overlay(**args)


def test_depth_range_ignores_the_far_plane():
    depth = np.full((10, 10), 125.0, np.float32)  # the empty background at the far plane
    depth[:6] = np.linspace(1.0, 3.0, 60).reshape(6, 10)
    depth[0, 0] = np.inf
    near, far = render._depth_range(depth, 125.0)
    assert 1.0 <= near < 1.1 and 2.9 < far <= 3.0


def test_contact_sheet_labels_each_tile():
    sheet = render._contact_sheet(["reach_target", "push_button"], 32, 0)
    # two tiles of 32 px drawn 8x (256 px) side by side, under a 22 px label band
    assert sheet.shape == (256 + 22, 512, 3)
    band = sheet[:22]
    assert (band < 128).any(-1).sum() > 50  # dark text on the white band
    assert sheet[22:].std() > 10  # the scenes


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # reading the MP4 back starts ffmpeg after JAX
def test_episode_visuals_are_a_figure_and_an_mp4(tmp_path):
    from envs.tasks import get_task
    from envs.tasks.base import TaskCamera

    task = get_task("reach_target", 32)
    seed = 3
    scene = task.reset(seed)
    with TaskCamera(task) as cam:
        rgb = cam.rgb(scene)
    expert = task.expert_motion(scene)
    cands = np.stack([expert, expert + 0.02])[None].astype(np.float32)  # [E=1, K=2, 101, 11]
    test = types.SimpleNamespace(meta={"image_size": 32}, rgb=rgb[None], seeds=np.array([seed]))
    result = {"episode_success": [True], "candidate_used": [0]}
    visualize.save_episode_visuals(tmp_path, "reach_target", test, cands, np.array([[-1.0, 2.0]]), result, None)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["reach_target_000_ok.mp4", "reach_target_000_ok.png"]
    assert iio.imread(tmp_path / "reach_target_000_ok.png").shape == (512, 512, 3)
    frames = iio.imread(tmp_path / "reach_target_000_ok.mp4", index=None, plugin="FFMPEG")
    assert frames.shape == (26, 256, 256, 3)  # the start, then every 4th of 101 waypoints
