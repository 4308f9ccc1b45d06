"""The default scene (Panda, table, one cube) and a scripted pick-up of the cube.

Used by ``bin/render``, ``bin/execute`` and the tests of the execution pipeline; the
nine tasks build their own scenes the same way.
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.execution import SceneBatch, World
from envs.scripted import Keyframe, keyframes_to_motion

CUBE_LIFT_HEIGHT = 0.1  # metres above its resting height
DOWN = np.diag([1.0, -1.0, -1.0])  # TCP z pointing at the table


def default_world(image_size: int = 256) -> World:
    return World.from_xml(panda.default_scene_xml(), image_size)


def _cube_z_index(world: World) -> int:
    return int(world.model.joint("cube_free").qposadr[0]) + 2


def cube_lifted(world: World):
    """Success predicate of the default scene: the cube is 10 cm above where it rests."""
    index = _cube_z_index(world)
    rest = float(world.model.qpos0[index])

    def success(qpos: np.ndarray, scenes: SceneBatch) -> np.ndarray:
        return qpos[..., index] > rest + CUBE_LIFT_HEIGHT

    return success


def pick_cube_motion(world: World, cube_xy=(0.5, 0.0)) -> np.ndarray:
    """A ``[101, 11]`` motion that grasps the cube at ``cube_xy`` and lifts it 20 cm."""
    from envs.kinematics import forward_kinematics

    tcp_pos, tcp_rot, _, _ = forward_kinematics(world.chain, np.asarray(panda.HOME_QPOS, np.float32))
    grip_z = panda.TABLE_HEIGHT + 0.02
    x, y = cube_xy
    start = Keyframe(tuple(np.asarray(tcp_pos)), np.asarray(tcp_rot, float), 1.0, 0.0)
    keyframes = [
        Keyframe((x, y, grip_z + 0.12), DOWN, 1.0, 1.5),
        Keyframe((x, y, grip_z), DOWN, 1.0, 1.0),
        Keyframe((x, y, grip_z), DOWN, 0.0, 0.6),
        Keyframe((x, y, grip_z + 0.22), DOWN, 0.0, 1.5),
    ]
    return keyframes_to_motion(world.camera, start, keyframes)


def default_scenes(world: World, n: int = 1) -> SceneBatch:
    return world.default_scenes(n)
