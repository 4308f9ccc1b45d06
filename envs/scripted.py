"""Scripted motions from keyframes: the building block of the experts and the demo.

A keyframe is a world TCP pose, a gripper state and the time to get there from the
previous keyframe. Between keyframes the position follows a minimum-jerk profile
along the straight line and the orientation a slerp on the same profile; the gripper
switches at the keyframe it is given for. The densely sampled trajectory is converted
to the camera frame and resampled into the 101-pose motion with the splines of
:func:`envs.motion.resample_episode`, exactly like a recorded episode.
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from envs import motion as motion_lib
from envs.camera import Camera


@dataclasses.dataclass(frozen=True)
class Keyframe:
    position: tuple[float, float, float]  # world, metres
    rotation: np.ndarray  # [3, 3] world orientation of the TCP
    grasp: float  # 1 = open, 0 = closed, applied on arrival
    duration: float  # seconds from the previous keyframe


def _min_jerk(s: np.ndarray) -> np.ndarray:
    return 10 * s**3 - 15 * s**4 + 6 * s**5


def dense_trajectory(start: Keyframe, keyframes: list[Keyframe], rate: float = 50.0):
    """Sample the keyframe path at ``rate`` Hz -> (times [F], positions [F, 3],
    rotations [F, 3, 3], grasp [F])."""
    times, pos, rot, grasp = [0.0], [np.asarray(start.position, float)], [np.asarray(start.rotation)], [start.grasp]
    prev, t0 = start, 0.0
    for kf in keyframes:
        if kf.duration <= 0:
            raise ValueError("keyframe durations must be positive")
        n = max(2, int(round(kf.duration * rate)))
        s = _min_jerk(np.arange(1, n + 1) / n)
        p0, p1 = np.asarray(prev.position, float), np.asarray(kf.position, float)
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([prev.rotation, kf.rotation])))
        times.extend(t0 + kf.duration * np.arange(1, n + 1) / n)
        pos.extend(p0 + s[:, None] * (p1 - p0))
        rot.extend(slerp(s).as_matrix())
        grasp.extend([prev.grasp] * (n - 1) + [kf.grasp])
        prev, t0 = kf, t0 + kf.duration
    return np.array(times), np.array(pos), np.array(rot), np.array(grasp, float)


def world_trajectory_to_motion(camera: Camera, times, positions, rotations, grasp) -> np.ndarray:
    """A world-frame TCP trajectory (any number of frames) -> ``[101, 11]`` motion."""
    xyz_cam = camera.world_to_camera(positions)
    uv = motion_lib.normalize_uv(camera.project(positions), camera.image_size)
    uvz = np.concatenate([uv, xyz_cam[:, 2:3]], axis=1)
    rot_cam = np.einsum("ji,fjk->fik", camera.rotation, rotations)
    return motion_lib.resample_episode(times, uvz, rot_cam, grasp)


def keyframes_to_motion(camera: Camera, start: Keyframe, keyframes: list[Keyframe]) -> np.ndarray:
    return world_trajectory_to_motion(camera, *dense_trajectory(start, keyframes))
