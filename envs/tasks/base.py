"""What every task provides, and the shared machinery: seeded resets, placements, grasp checks.

A task is a scene (objects added to the Panda/table model), a seeded randomisation of
that scene, a success predicate computed from simulator state after each waypoint, and
a scripted expert given as keyframes. Randomised fixed bodies (bases, racks, bins) are
moved per episode through ``body_pos``/``body_quat``; free objects through ``qpos``.
Everything a predicate needs is in the recorded ``qpos`` and the episode's placements,
so it is the same on both physics back-ends.
"""
from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import jax
import mujoco
import numpy as np

from envs import panda
from envs.execution import SceneBatch, World
from envs.kinematics import forward_kinematics
from envs.scripted import Keyframe, keyframes_to_motion

#: TCP pointing straight down at the table, fingers closing along world y.
DOWN = np.diag([1.0, -1.0, -1.0])


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def down_grasp(yaw: float) -> np.ndarray:
    """TCP pointing down, turned by ``yaw`` about the world z axis (fingers close along the
    turned y axis). The Panda's hand is symmetric under a half turn, so yaw is folded into
    [-pi/2, pi/2] to keep joint 7 away from its limits."""
    yaw = (yaw + np.pi / 2) % np.pi - np.pi / 2
    return yaw_matrix(yaw) @ DOWN


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def planar_offset(origin_xy, yaw: float, local_xy) -> np.ndarray:
    """``origin_xy + R(yaw) local_xy``: where a point given in a yawed base lands on the table."""
    return np.asarray(origin_xy, float) + yaw_matrix(yaw)[:2, :2] @ np.asarray(local_xy, float)


def quat_rotate(quat: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Rotate ``vec [..., 3]`` by unit quaternions ``quat [..., 4]`` (w, x, y, z), numpy."""
    w, xyz = quat[..., :1], quat[..., 1:]
    t = 2.0 * np.cross(xyz, vec)
    return vec + w * t + np.cross(xyz, t)


@dataclasses.dataclass(frozen=True)
class Scene:
    """One episode's start, rebuilt exactly from ``seed``: the randomised values, the
    initial ``qpos [nq]`` and the body placements ``body_pos [nbody, 3]``, ``body_quat [nbody, 4]``."""

    seed: int
    params: dict
    qpos: np.ndarray
    body_pos: np.ndarray
    body_quat: np.ndarray


class Task(abc.ABC):
    """Subclasses set ``name`` and ``abbr`` and implement the abstract methods."""

    name: ClassVar[str]
    abbr: ClassVar[str]

    def __init__(self, image_size: int = 256):
        self.world = World.from_xml(self.scene_xml(), image_size)
        self.model = self.world.model
        tcp_pos, tcp_rot, _, _ = forward_kinematics(self.world.chain, np.asarray(panda.HOME_QPOS, np.float32))
        self.home_pose = (np.asarray(tcp_pos, np.float64), np.asarray(tcp_rot, np.float64))
        self._fk = jax.jit(jax.vmap(lambda q: forward_kinematics(self.world.chain, q)[:2]))

    # ------------------------------------------------------------------ to implement
    @abc.abstractmethod
    def scene_xml(self) -> str:
        """The full MJCF (``panda.scene_xml(objects=..., pairs=...)``)."""

    @abc.abstractmethod
    def randomize(self, rng: np.random.Generator) -> dict:
        """Draw the episode's random values (plain floats and arrays)."""

    @abc.abstractmethod
    def place(self, params: dict, qpos: np.ndarray, body_pos: np.ndarray, body_quat: np.ndarray) -> None:
        """Write the episode's placements into the (copied) arrays, in place."""

    @abc.abstractmethod
    def success(self, qpos: np.ndarray, scenes: SceneBatch) -> np.ndarray:
        """``qpos [E, W, nq]`` after each waypoint -> ``bool [E, W]``: the condition holds."""

    @abc.abstractmethod
    def expert_keyframes(self, scene: Scene) -> list[Keyframe]:
        """The scripted expert's keyframes from the home pose (approach, grasp/press, carry, release)."""

    # ------------------------------------------------------------------ shared
    def reset(self, seed: int) -> Scene:
        """The episode of ``seed``: the same seed always gives the same scene."""
        rng = np.random.default_rng(seed)
        params = self.randomize(rng)
        qpos = self.world.home_qpos()
        body_pos, body_quat = self.model.body_pos.copy(), self.model.body_quat.copy()
        self.place(params, qpos, body_pos, body_quat)
        return Scene(int(seed), params, qpos, body_pos, body_quat)

    def batch(self, scenes: list[Scene]) -> SceneBatch:
        return SceneBatch(
            np.stack([s.qpos for s in scenes]),
            np.stack([s.body_pos for s in scenes]),
            np.stack([s.body_quat for s in scenes]),
        )

    def expert_motion(self, scene: Scene) -> np.ndarray:
        """The expert's ``[101, 11]`` motion for ``scene``."""
        start = Keyframe(tuple(self.home_pose[0]), self.home_pose[1], 1.0, 0.0)
        return keyframes_to_motion(self.world.camera, start, self.expert_keyframes(scene))

    # ---- ids and state access used by subclasses
    def body_id(self, name: str) -> int:
        return mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)

    def qpos_addr(self, joint: str) -> int:
        return int(self.model.joint(joint).qposadr[0])

    def set_body(self, body_pos, body_quat, name: str, xy, yaw: float = 0.0, z: float | None = None) -> None:
        i = self.body_id(name)
        body_pos[i, :2] = xy
        if z is not None:
            body_pos[i, 2] = z
        body_quat[i] = yaw_quat(yaw)

    def set_free(self, qpos, joint: str, xyz, yaw: float = 0.0) -> None:
        a = self.qpos_addr(joint)
        qpos[a : a + 3] = xyz
        qpos[a + 3 : a + 7] = yaw_quat(yaw)

    def free_pose(self, qpos: np.ndarray, joint: str) -> tuple[np.ndarray, np.ndarray]:
        """A free joint's (position ``[..., 3]``, quaternion ``[..., 4]``) from qpos ``[..., nq]``."""
        a = self.qpos_addr(joint)
        return qpos[..., a : a + 3], qpos[..., a + 3 : a + 7]

    def free_point(self, qpos: np.ndarray, joint: str, local) -> np.ndarray:
        """World position of a point given in a free body's frame, ``[..., 3]``."""
        pos, quat = self.free_pose(qpos, joint)
        return pos + quat_rotate(quat, np.broadcast_to(np.asarray(local, float), pos.shape))

    def in_body_frame(self, points: np.ndarray, scenes: SceneBatch, body: str) -> np.ndarray:
        """World ``points [E, ..., 3]`` -> coordinates in each episode's placement of the fixed ``body``."""
        i = self.body_id(body)
        lead = (len(points),) + (1,) * (points.ndim - 2)
        origin = scenes.body_pos[:, i].reshape(lead + (3,))
        inverse = (scenes.body_quat[:, i] * np.array([1.0, -1.0, -1.0, -1.0])).reshape(lead + (4,))
        return quat_rotate(np.broadcast_to(inverse, points.shape[:-1] + (4,)), points - origin)

    def tcp_pose(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP (position ``[..., 3]``, rotation ``[..., 3, 3]``) from qpos ``[..., nq]``."""
        q = qpos[..., self.world.chain.qpos_index]
        flat = q.reshape(-1, 7).astype(np.float32)
        pos, rot = self._fk(flat)
        return (np.asarray(pos, np.float64).reshape(*q.shape[:-1], 3),
                np.asarray(rot, np.float64).reshape(*q.shape[:-1], 3, 3))

    def finger_opening(self, qpos: np.ndarray) -> np.ndarray:
        return qpos[..., self.qpos_addr("finger_left")]

    def nothing_grasped(self, qpos: np.ndarray) -> np.ndarray:
        """The gripper is open (RLBench: no object in the gripper's grasped list)."""
        return self.finger_opening(qpos) > 0.03

    def held(self, qpos: np.ndarray, point: np.ndarray, half_width: float) -> np.ndarray:
        """The object whose grasp ``point [..., 3]`` is given is held between the fingers:
        the point lies within the fingertips' box in the TCP frame, and the fingers are
        closed onto something about ``half_width`` thick (neither open nor shut)."""
        tcp, rot = self.tcp_pose(qpos)
        local = np.einsum("...ji,...j->...i", rot, point - tcp)
        inside = (np.abs(local[..., 0]) < 0.03) & (np.abs(local[..., 1]) < half_width + 0.01) & (
            np.abs(local[..., 2]) < 0.035)
        opening = self.finger_opening(qpos)
        return inside & (opening > 0.5 * half_width) & (opening < min(half_width + 0.006, 0.039))


class TaskCamera:
    """Renders a task's scenes from the front camera. It owns a copy of the task's model
    into which each scene's placements are written before rendering."""

    def __init__(self, task: Task, image_size: int | None = None):
        import copy

        from envs.camera import SceneRenderer

        self.task = task
        self.model = copy.copy(task.model)
        self.data = mujoco.MjData(self.model)
        self.image_size = image_size or task.world.camera.image_size
        self._renderer = SceneRenderer(self.model, self.image_size)

    def _set(self, scene: Scene, qpos: np.ndarray | None = None) -> None:
        self.model.body_pos[:] = scene.body_pos
        self.model.body_quat[:] = scene.body_quat
        self.data.qpos[:] = scene.qpos if qpos is None else qpos
        self.data.qvel[:] = 0
        mujoco.mj_forward(self.model, self.data)

    def rgb(self, scene: Scene, qpos: np.ndarray | None = None) -> np.ndarray:
        """RGB uint8 ``[S, S, 3]`` of the scene (at its start, or at ``qpos``), without depth."""
        self._set(scene, qpos)
        return self._renderer.rgb(self.data)

    def rgbd(self, scene: Scene, qpos: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """RGB uint8 ``[S, S, 3]`` and metric depth float32 ``[S, S]`` of the scene (at its
        start, or at ``qpos``)."""
        self._set(scene, qpos)
        return self._renderer.rgbd(self.data)

    def close(self) -> None:
        self._renderer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
