"""Demonstration datasets: generation (scripted experts), storage, loading.

Layout, one directory per task and split (``DIR/<task>/<split>/``), every array a plain
``.npy`` file that :func:`load_split` memory-maps:

==============  =========================  ==============================================
file            dtype, shape               content
==============  =========================  ==============================================
``rgb.npy``     uint8 ``[N, S, S, 3]``     first frame of each episode, front camera
``depth.npy``   float32 ``[N, S, S]``      its metric depth (m, along the optical axis)
``motions.npy`` float32 ``[N, 101, 11]``   the expert's motion (``envs.motion`` layout)
``seeds.npy``   int64 ``[N]``              seed that rebuilds each scene (``task.reset``)
``meta.json``   JSON                       task, split, counts, image size, camera K and
                                           pose, generator version, base seed, timing
==============  =========================  ==============================================

Writing is crash-safe: finished batches go to ``DIR/<task>/.<split>.partial-<key>/``
(each file written under a temporary name, then renamed), so an interrupted run resumes
where it stopped; the split appears under its final name only when complete, by one
rename of a fully written directory. Seeds are tried in a fixed order and successes are
kept in that order, so a run gives the same bytes however often it was interrupted.
"""
from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from envs import motion as motion_lib
from envs.progress import Progress

GENERATOR_VERSION = 1
SPLITS = ("train", "test")
_SPLIT_OFFSET = {"train": 0, "test": 5_000_000}
_SEED_STRIDE = 10_000_000
FILES = ("rgb.npy", "depth.npy", "motions.npy", "seeds.npy")


def episode_seed(base_seed: int, split: str, index: int) -> int:
    """The seed of the ``index``-th scene tried for ``split``: train and test never share one,
    and neither do different base seeds."""
    if not 0 <= index < _SPLIT_OFFSET["test"]:
        raise ValueError(f"episode index {index} out of range")
    return base_seed * _SEED_STRIDE + _SPLIT_OFFSET[split] + index


@dataclass(frozen=True)
class Split:
    """A loaded split; arrays are read-only memory maps."""

    rgb: np.ndarray
    depth: np.ndarray
    motions: np.ndarray
    seeds: np.ndarray
    meta: dict

    def __len__(self) -> int:
        return len(self.seeds)


class DatasetError(Exception):
    """A dataset is missing, incomplete or inconsistent."""


def size_in_name(root: str | Path) -> int | None:
    """The image size a dataset root's name gives (``data/64px`` -> 64), else None."""
    match = re.fullmatch(r"(\d+)px", Path(root).name)
    return int(match.group(1)) if match else None


def split_dir(root: str | Path, task: str, split: str) -> Path:
    return Path(root) / task / split


def load_split(root: str | Path, task: str, split: str, image_size: int | None = None) -> Split:
    """Memory-map ``root/<task>/<split>``; raise :class:`DatasetError` saying what is wrong.
    ``image_size``: the size the caller needs, for the command a missing split's error prints
    (default: the size in the root's name, ``data/<size>px``)."""
    path = split_dir(root, task, split)
    meta_path = path / "meta.json"
    if not meta_path.is_file():
        size = image_size or size_in_name(root)
        raise DatasetError(
            f"no complete dataset at {path} (meta.json missing); generate it with "
            f"`bin/generate_data --task {task} --out {root}" + (f" --image-size {size}`" if size else "`"))
    arrays = {}
    for name in ("meta.json", *FILES):
        try:
            if name == "meta.json":
                meta = json.loads(meta_path.read_text())
            else:
                arrays[name] = np.load(path / name, mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError, EOFError) as err:
            raise DatasetError(f"corrupt dataset at {path}: {name}: {err}") from err
    if not isinstance(meta, dict):
        raise DatasetError(f"corrupt dataset at {path}: meta.json holds a {type(meta).__name__}, expected a JSON object")
    n, s = meta.get("episodes"), meta.get("image_size")
    if not isinstance(n, int) or n < 1 or not isinstance(s, int) or s < 1:
        raise DatasetError(f"corrupt dataset at {path}: meta.json says episodes={n!r}, image_size={s!r}; "
                           "expected positive integers (a split holds at least one episode)")
    expected = {
        "rgb.npy": ((n, s, s, 3), np.uint8),
        "depth.npy": ((n, s, s), np.float32),
        "motions.npy": ((n, motion_lib.NUM_STEPS, motion_lib.POSE_DIM), np.float32),
        "seeds.npy": ((n,), np.int64),
    }
    for f, (shape, dtype) in expected.items():
        if arrays[f].shape != shape or arrays[f].dtype != dtype:
            raise DatasetError(
                f"corrupt dataset at {path}: {f} is {arrays[f].dtype}{list(arrays[f].shape)}, "
                f"expected {np.dtype(dtype)}{list(shape)}"
            )
    if meta.get("task") != task or meta.get("split") != split:
        raise DatasetError(f"{path} holds {meta.get('task')}/{meta.get('split')}, not {task}/{split}")
    # Motions are small (N x 4.4 kB): every load checks them; images are checked where used.
    bad = motion_lib.count_non_finite(arrays["motions.npy"])
    if bad:
        raise DatasetError(f"corrupt dataset at {path}: motions.npy contains {bad} NaN or inf value(s); "
                           "expected finite motions (regenerate the split)")
    return Split(arrays["rgb.npy"], arrays["depth.npy"], arrays["motions.npy"], arrays["seeds.npy"], meta)


def atomic_save(path: Path, array: np.ndarray) -> None:
    """Write ``array`` as ``.npy`` under a temporary name, synced, then rename: never a half file."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        np.save(f, array, allow_pickle=False)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` under a temporary name, then rename: never a half file."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _read_chunk(path: Path) -> dict[str, np.ndarray]:
    """The arrays of one finished batch of a partial split; ``DatasetError`` naming the file if damaged."""
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in ("rgb", "depth", "motions", "seeds", "attempts", "successes")}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as err:
        raise DatasetError(f"corrupt batch file {path} in an unfinished split ({type(err).__name__}: {err}); "
                           "delete it and rerun to generate that batch again") from err


@contextlib.contextmanager
def writer_lock(lock_file: Path, error: type[Exception] = DatasetError):
    """Hold ``lock_file`` exclusively while writing what it guards: a second writer fails at once
    with ``error`` naming the first process, instead of redoing its work beside it. The operating
    system releases the lock when its holder exits, however it exits, so a dead writer's lock is
    taken over."""
    lock_file.parent.mkdir(parents=True, exist_ok=True)
    directory = lock_file.parent
    with open(lock_file, "a+") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            f.seek(0)
            holder = f.read().strip() or "another process"
            raise error(f"{directory} is being written by {holder}; wait for it to finish, or use another "
                        "directory") from None
        f.seek(0)
        f.truncate()
        f.write(f"process {os.getpid()}")
        f.flush()
        try:
            yield
        finally:
            f.seek(0)
            f.truncate()
            fcntl.flock(f, fcntl.LOCK_UN)


def generate_split(
    task,
    split: str,
    episodes: int,
    root: str | Path,
    base_seed: int = 0,
    batch: int = 64,
    workers: int | None = None,
    verbose: bool = True,
) -> Path:
    """Run ``task``'s expert on successive seeds until ``episodes`` succeed; write the split.

    Returns the split's directory. Skips work already done (a complete split is left as is;
    an interrupted one resumes). One process writes a split at a time: a second one fails
    naming the first.
    """
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {SPLITS}")
    if episodes < 1:
        raise ValueError(f"episodes must be positive, got {episodes}")
    final = split_dir(root, task.name, split)
    if (final / "meta.json").is_file():
        return final
    if final.exists():  # the finished split is published by renaming onto this path
        raise DatasetError(f"{final} exists but is not a complete split (no meta.json); move it away or delete it, "
                           "then rerun")
    with writer_lock(final.parent / f".{split}.lock"):
        if (final / "meta.json").is_file():  # finished by the writer that held the lock before
            return final
        return _write_split(task, split, episodes, final, base_seed, batch, workers, verbose)


def _write_split(task, split: str, episodes: int, final: Path, base_seed: int, batch: int, workers,
                 verbose: bool) -> Path:
    """:func:`generate_split`'s work, under its lock: batches to the partial directory, then the split."""
    from envs import execution
    from envs.tasks.base import TaskCamera

    size = task.world.camera.image_size
    key = hashlib.sha1(json.dumps([GENERATOR_VERSION, task.name, split, episodes, size, base_seed, batch]).encode()).hexdigest()[:10]
    partial = final.parent / f".{split}.partial-{key}"
    partial.mkdir(parents=True, exist_ok=True)

    chunks = sorted(partial.glob("chunk_*.npz"))
    kept = 0
    for c in chunks:
        kept += len(_read_chunk(c)["seeds"])
    next_batch = len(chunks)
    progress = Progress(f"{task.name} {split}", episodes) if verbose else None
    with TaskCamera(task) as camera:
        while kept < episodes:
            if next_batch * batch >= _SPLIT_OFFSET["test"]:
                raise RuntimeError(f"{task.name}: the expert failed on too many seeds")
            seeds = [episode_seed(base_seed, split, next_batch * batch + i) for i in range(batch)]
            scenes = [task.reset(s) for s in seeds]
            motions = np.stack([task.expert_motion(s) for s in scenes])
            result = execution.execute(task.world, motions, task.batch(scenes), task.success, "mujoco",
                                       threads=workers)
            ok = np.nonzero(result.success)[0][: episodes - kept]
            images = [camera.rgbd(scenes[i]) for i in ok]
            chunk = {
                "rgb": np.stack([im[0] for im in images]) if len(ok) else np.zeros((0, size, size, 3), np.uint8),
                "depth": np.stack([im[1] for im in images]) if len(ok) else np.zeros((0, size, size), np.float32),
                "motions": motions[ok],
                "seeds": np.asarray(seeds, np.int64)[ok],
                "attempts": np.int64(batch),
                "successes": np.int64(result.success.sum()),
            }
            path = partial / f"chunk_{next_batch:06d}.npz"
            # The temporary name must not match ``chunk_*.npz``: a run killed while writing
            # leaves it behind, and the resume must neither count nor load it.
            tmp = partial / f"chunk_{next_batch:06d}.npz.tmp"
            with open(tmp, "wb") as f:
                np.savez(f, **chunk)
                f.flush()
                os.fsync(f.fileno())
            tmp.replace(path)
            kept += len(ok)
            next_batch += 1
            if progress:
                progress.update(kept, f"(expert success {result.success.mean():.0%} in the last batch)")
    if progress:
        progress.close()

    # Assemble the split in a hidden directory, then publish it with one rename.
    parts = {k: [] for k in ("rgb", "depth", "motions", "seeds")}
    attempts = successes = 0
    for c in sorted(partial.glob("chunk_*.npz")):
        z = _read_chunk(c)
        for k in parts:
            parts[k].append(z[k])
        attempts += int(z["attempts"])
        successes += int(z["successes"])
    assembling = final.parent / f".{split}.assembling-{key}"
    shutil.rmtree(assembling, ignore_errors=True)
    assembling.mkdir(parents=True)
    for k, arrays in parts.items():
        atomic_save(assembling / f"{k}.npy", np.concatenate(arrays)[:episodes])
    cam = task.world.camera
    meta = {
        "task": task.name,
        "split": split,
        "episodes": episodes,
        "image_size": size,
        "intrinsics": cam.intrinsics.tolist(),
        "camera_position": cam.position.tolist(),
        "camera_rotation": cam.rotation.tolist(),
        "depth": "metric metres along the optical axis",
        "generator_version": GENERATOR_VERSION,
        "base_seed": base_seed,
        "expert_attempts": attempts,
        "expert_success_rate": successes / attempts,
    }
    atomic_write_text(assembling / "meta.json", json.dumps(meta, indent=2))
    assembling.replace(final)
    shutil.rmtree(partial, ignore_errors=True)
    return final
