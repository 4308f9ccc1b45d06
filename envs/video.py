"""Rollout videos: render an executed episode frame by frame and write an animated GIF.

The GIF writer is self-contained (no imaging library): frames are quantised to a fixed
6 x 7 x 6 colour cube and LZW-coded with a clear code every few hundred literals, which
keeps codes 9 bits wide — simple and valid, if not the smallest file.
"""
from __future__ import annotations

import struct
from pathlib import Path

import mujoco
import numpy as np

from envs.camera import SceneRenderer
from envs.execution import SceneBatch, World

_LEVELS = (6, 7, 6)  # red, green, blue levels of the palette (252 colours)


def _palette() -> np.ndarray:
    r, g, b = np.meshgrid(*(np.linspace(0, 255, n).round() for n in _LEVELS), indexing="ij")
    colours = np.stack([r, g, b], -1).reshape(-1, 3).astype(np.uint8)
    return np.concatenate([colours, np.zeros((256 - len(colours), 3), np.uint8)])


def _quantise(rgb: np.ndarray) -> np.ndarray:
    idx = [np.rint(rgb[..., c].astype(np.float32) / 255 * (n - 1)).astype(np.int32) for c, n in enumerate(_LEVELS)]
    return ((idx[0] * _LEVELS[1] + idx[1]) * _LEVELS[2] + idx[2]).astype(np.uint8)


def _lzw_literals(indices: np.ndarray) -> bytes:
    """LZW code stream (minimum code size 8) made of literals only, 9-bit codes."""
    clear, end, per_clear = 256, 257, 250
    codes = []
    flat = indices.reshape(-1).tolist()
    for i in range(0, len(flat), per_clear):
        codes.append(clear)
        codes.extend(flat[i:i + per_clear])
    codes.append(end)
    bits = np.zeros(9 * len(codes), np.uint8)
    arr = np.asarray(codes, np.uint16)
    for b in range(9):  # little-endian bit order within each code, codes packed LSB first
        bits[b::9] = (arr >> b) & 1
    data = np.packbits(bits, bitorder="little").tobytes()
    return b"".join(bytes([len(data[i:i + 255])]) + data[i:i + 255] for i in range(0, len(data), 255)) + b"\x00"


def write_gif(path: str | Path, frames: np.ndarray, frame_ms: int = 80) -> None:
    """Write uint8 ``frames [F, H, W, 3]`` as a looping animated GIF, atomically."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"write_gif expects uint8 frames [F, H, W, 3], got {frames.dtype} {frames.shape}")
    _, h, w, _ = frames.shape
    out = [b"GIF89a", struct.pack("<HHBBB", w, h, 0xF7, 0, 0), _palette().tobytes(),
           b"!\xff\x0bNETSCAPE2.0\x03\x01\x00\x00\x00"]
    for frame in frames:
        out.append(b"!\xf9\x04\x04" + struct.pack("<H", max(1, frame_ms // 10)) + b"\x00\x00")
        out.append(b"," + struct.pack("<HHHHB", 0, 0, w, h, 0) + b"\x08" + _lzw_literals(_quantise(frame)))
    out.append(b";")
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(b"".join(out))
    tmp.replace(path)


def render_rollout(world: World, scenes: SceneBatch, qpos: np.ndarray, episode: int = 0, size: int = 256,
                   every: int = 4) -> np.ndarray:
    """Front-camera RGB frames ``[F, size, size, 3]`` of episode ``episode`` of an executed
    batch: its initial state, then ``qpos [E, W, nq]`` after every ``every``-th waypoint."""
    model = scenes.model_for(world.model, episode)
    data = mujoco.MjData(model)
    states = [scenes.qpos[episode]] + list(qpos[episode, every - 1::every])
    frames = []
    with SceneRenderer(model, size) as renderer:
        for q in states:
            data.qpos[:] = q
            mujoco.mj_forward(model, data)
            frames.append(renderer.rgbd(data)[0])
    return np.stack(frames)
