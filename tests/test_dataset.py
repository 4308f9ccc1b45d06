"""Datasets: round trip, crash-safe resumable writing, seeds; evaluation of world methods."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from envs import dataset, evaluation
from envs.tasks import get_task
from envs.tasks.base import TaskCamera

ROOT = Path(__file__).resolve().parents[1]
SIZE = 32


@pytest.fixture(scope="module")
def task():
    return get_task("reach_target", SIZE)


@pytest.fixture(scope="module")
def data(tmp_path_factory, task):
    root = tmp_path_factory.mktemp("data")
    dataset.generate_split(task, "train", 10, root, batch=8, verbose=False)
    dataset.generate_split(task, "test", 5, root, batch=8, verbose=False)
    return root


def test_round_trip(data, task):
    train = dataset.load_split(data, "reach_target", "train")
    assert train.rgb.shape == (10, SIZE, SIZE, 3) and train.rgb.dtype == np.uint8
    assert train.depth.shape == (10, SIZE, SIZE) and train.depth.dtype == np.float32
    assert train.motions.shape == (10, 101, 11) and train.motions.dtype == np.float32
    assert isinstance(train.rgb, np.memmap)
    meta = train.meta
    assert meta["generator_version"] == dataset.GENERATOR_VERSION and meta["image_size"] == SIZE
    np.testing.assert_allclose(meta["intrinsics"], task.world.camera.intrinsics)
    # Each stored seed rebuilds its scene: same image, same expert motion.
    scene = task.reset(int(train.seeds[3]))
    with TaskCamera(task) as cam:
        rgb, depth = cam.rgbd(scene)
    np.testing.assert_array_equal(rgb, train.rgb[3])
    np.testing.assert_array_equal(depth, train.depth[3])
    np.testing.assert_array_equal(task.expert_motion(scene), train.motions[3])


def test_train_and_test_seeds_are_disjoint(data):
    train = dataset.load_split(data, "reach_target", "train")
    test = dataset.load_split(data, "reach_target", "test")
    assert not set(train.seeds.tolist()) & set(test.seeds.tolist())
    assert dataset.episode_seed(0, "test", 0) != dataset.episode_seed(1, "train", 0)


def test_interrupted_generation_resumes_to_identical_bytes(tmp_path, data, task, monkeypatch):
    calls = {"n": 0}
    real = np.savez

    def crash_on_second_chunk(path, **arrays):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt("killed")
        real(path, **arrays)

    monkeypatch.setattr(dataset.np, "savez", crash_on_second_chunk)
    with pytest.raises(KeyboardInterrupt):
        dataset.generate_split(task, "train", 10, tmp_path, batch=8, verbose=False)
    monkeypatch.setattr(dataset.np, "savez", real)
    # Nothing loads as complete; the finished chunk is kept for the resume.
    with pytest.raises(dataset.DatasetError, match="no complete dataset"):
        dataset.load_split(tmp_path, "reach_target", "train")
    assert len(list(tmp_path.glob("reach_target/.train.partial-*/chunk_*.npz"))) == 1
    dataset.generate_split(task, "train", 10, tmp_path, batch=8, verbose=False)
    for f in dataset.FILES + ("meta.json",):
        assert (tmp_path / "reach_target/train" / f).read_bytes() == (data / "reach_target/train" / f).read_bytes()
    assert sorted(p.name for p in (tmp_path / "reach_target").iterdir()) == [".train.lock", "train"]  # no partial


def test_corrupt_dataset_fails_clearly(tmp_path, data):
    import shutil

    shutil.copytree(data / "reach_target", tmp_path / "reach_target")
    np.save(tmp_path / "reach_target/train/motions.npy", np.zeros((10, 101, 9), np.float32))
    with pytest.raises(dataset.DatasetError, match="motions.npy"):
        dataset.load_split(tmp_path, "reach_target", "train")
    (tmp_path / "reach_target/train/rgb.npy").write_bytes(b"garbage")
    with pytest.raises(dataset.DatasetError, match="corrupt"):
        dataset.load_split(tmp_path, "reach_target", "train")


def test_fallback_to_next_candidate_only_when_abandoned(data, task):
    test = dataset.load_split(data, "reach_target", "test")
    scenes = [task.reset(int(s)) for s in test.seeds[:2]]
    good = np.asarray(test.motions[:2])
    far = good.copy()
    far[:, :, 2] += 4.0  # every waypoint out of reach: abandoned
    wrong = np.asarray(test.motions[[1, 0]])  # reachable but the other scene's target
    out = evaluation.execute_candidates(task, scenes, np.stack([far, good], axis=1), "mujoco")
    assert out["success"].all() and out["candidate"].tolist() == [1, 1]
    out = evaluation.execute_candidates(task, scenes, np.stack([wrong, good], axis=1), "mujoco")
    assert not out["success"].any() and out["candidate"].tolist() == [0, 0]


def test_evaluate_command_expert_and_blind(data, tmp_path):
    out = tmp_path / "r.json"
    cmd = [sys.executable, "bin/evaluate", "--task", "reach_target", "--method", "expert",
           "--data", str(data), "--json", str(out)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(out.read_text())
    assert {k: res[k] for k in ("task", "method", "episodes", "successes", "success_rate")} == {
        "task": "reach_target", "method": "expert", "episodes": 5, "successes": 5, "success_rate": 1.0}
    assert "| expert |" in proc.stdout and "RT" in proc.stdout
    cmd[5] = "blind"
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(out.read_text())["success_rate"] <= 0.4
