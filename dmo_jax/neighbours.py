"""Bank neighbours: for every motion of a split, the K training motions whose poses lie closest.

At prediction the EBM must tell apart, and the DMO must correct, the training motions of other
scenes that lie close to the scene (the bank's top n). Training on such motions needs, for each
training motion, its nearest *other* training motions, and the held-out ranking on them needs
each test motion's nearest training motions (the bank it meets at prediction).

Distance: the mean over the 101 poses of the 3-D distance between camera-frame positions (from
uv, z and the intrinsics), as ``losses.position_error``. Neighbours are computed once per split
and stored in it (``DATA/<task>/<split>/``)::

    neighbours.npy    int32 [N, K]   indices into the training split, nearest first
    neighbours.json   {k, fingerprint}: what they were computed from

Both are written atomically, the index file first, so a crash leaves either the old pair or a
fingerprint that no longer matches (and the neighbours are rebuilt). The fingerprint hashes the
query motions, the training motions, the intrinsics and K: neighbours are rebuilt when the data
changes, and the same data gives the same bytes.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from envs.motion import camera_positions

#: Neighbours stored per motion (the hard negatives and the held-out ranking draw from the first ones).
DEFAULT_K = 64
INDEX_FILE, INFO_FILE = "neighbours.npy", "neighbours.json"


def positions(motions: np.ndarray, intrinsics, image_size: int) -> np.ndarray:
    """Camera-frame positions ``float64 [N, 101, 3]`` of ``motions [N, 101, 11]``."""
    pos = camera_positions(jnp.asarray(motions, jnp.float32), jnp.asarray(intrinsics, jnp.float32), image_size)
    return np.asarray(pos, np.float64)


def nearest(query: np.ndarray, bank: np.ndarray, k: int, exclude_self: bool, chunk: int = 64) -> np.ndarray:
    """Indices ``int32 [Q, k]`` of the ``k`` motions of ``bank [N, 101, 3]`` (positions) closest to
    each of ``query [Q, 101, 3]`` by mean pose distance, nearest first (ties by index). With
    ``exclude_self`` the query is the bank itself and a motion is never its own neighbour."""
    limit = len(bank) - int(exclude_self)
    if not 1 <= k <= limit:
        raise ValueError(f"k must be in [1, {limit}] for a bank of {len(bank)} motions, got {k}")
    out = np.empty((len(query), k), np.int32)
    for start in range(0, len(query), chunk):
        q = query[start:start + chunk]
        dist = np.linalg.norm(q[:, None] - bank[None], axis=-1).mean(axis=-1)  # [c, N]
        if exclude_self:
            dist[np.arange(len(q)), np.arange(start, start + len(q))] = np.inf
        out[start:start + len(q)] = np.argsort(dist, axis=1, kind="stable")[:, :k]
    return out


def _fingerprint(query: np.ndarray, bank: np.ndarray, intrinsics, image_size: int, k: int) -> str:
    h = hashlib.sha256()
    for array in (query, bank, np.asarray(intrinsics, np.float64)):
        h.update(np.ascontiguousarray(array).tobytes())
    h.update(json.dumps([image_size, k, 1]).encode())
    return h.hexdigest()


def split_neighbours(split_path: str | Path, query: np.ndarray, bank: np.ndarray, intrinsics, image_size: int,
                     k: int = DEFAULT_K, is_bank: bool = False, log=None) -> np.ndarray:
    """The neighbours ``int32 [Q, k]`` among ``bank [N, 101, 11]`` of each of ``query [Q, 101, 11]``,
    the motions of the split stored at ``split_path``; read from there when they match the data,
    else computed and stored. ``is_bank``: the split is the training split itself (a motion is
    then never its own neighbour). A bank of fewer than ``k`` (other) motions gives them all."""
    from envs.dataset import atomic_save, atomic_write_text

    path = Path(split_path)
    k = min(k, len(bank) - int(is_bank))
    fingerprint = _fingerprint(query, bank, intrinsics, image_size, k)
    index_path, info_path = path / INDEX_FILE, path / INFO_FILE
    try:
        info = json.loads(info_path.read_text())
        if info.get("fingerprint") == fingerprint:
            index = np.load(index_path, allow_pickle=False)
            if index.shape == (len(query), k) and index.dtype == np.int32:
                return index
    except (OSError, ValueError):
        pass  # missing, torn or foreign: rebuilt below
    if log:
        log(f"computing the {k} nearest training motions of {len(query)} motions in {path}")
    bank_pos = positions(bank, intrinsics, image_size)
    query_pos = bank_pos if is_bank else positions(query, intrinsics, image_size)
    index = nearest(query_pos, bank_pos, k, exclude_self=is_bank)
    try:
        atomic_save(index_path, index)
        atomic_write_text(info_path, json.dumps({"k": k, "fingerprint": fingerprint}, indent=2))
    except OSError as err:  # a read-only dataset: used for this run, computed again by the next
        if log:
            log(f"cannot store the neighbours in {path} ({err.strerror or err}); they are used for this run only")
    return index
