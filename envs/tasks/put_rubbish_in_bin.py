"""PR: put the crumpled paper (rubbish) into the bin; two tomatoes are distractors.

As in RLBench, the rubbish and the two tomatoes stand on three spots of the task base
and the rubbish swaps place with one of the tomatoes (or stays), and the whole base
(bin and spots) is placed and turned about z at random. The expert picks the rubbish,
carries it over the bin, lowers it below the rim and lets go. Success: the rubbish is
inside the bin (release not required, as in RLBench).
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, down_grasp, planar_offset

TOP = panda.TABLE_HEIGHT
RUBBISH = 0.022  # half side of the paper ball's collision cube
TOMATO = 0.03
BIN_IN = 0.065  # inner half width of the (square) bin
BIN_H = 0.12  # bin height
WALL = 0.005
#: Spots on the base (base frame): where the rubbish and the two tomatoes start, and the bin.
SPOTS = np.array([[-0.06, 0.0], [0.07, 0.06], [-0.04, 0.14]])
BIN = np.array([0.0, -0.17])
BASE_REGION = (np.array([0.45, -0.12]), np.array([0.57, 0.12]))
BASE_YAW = np.pi / 4


def _tomato(name: str) -> str:
    return (
        f'<body name="{name}" pos="0.5 0.3 {TOP + TOMATO * 0.9:.4f}">'
        f'<geom name="{name}_vis" type="ellipsoid" size="{TOMATO} {TOMATO} {TOMATO * 0.85:.4f}" class="visual" '
        f'rgba="0.85 0.1 0.05 1"/>'
        f'<geom name="{name}_stalk_vis" type="cylinder" size="0.01 0.003" pos="0 0 {TOMATO * 0.85:.4f}" '
        f'class="visual" rgba="0.15 0.55 0.1 1"/></body>'
    )


class PutRubbishInBin(Task):
    name = "put_rubbish_in_bin"
    abbr = "PR"

    def scene_xml(self) -> str:
        blobs = ((0.008, 0.006, 0.006), (-0.008, -0.005, 0.004), (0.004, -0.009, -0.006), (-0.006, 0.008, -0.005))
        rubbish = (
            f'<body name="rubbish" pos="0.5 0 {TOP + RUBBISH}"><freejoint name="rubbish"/>'
            f'<geom name="rubbish" type="box" size="{RUBBISH} {RUBBISH} {RUBBISH}" mass="0.05" class="object" '
            f'rgba="0 0 0 0"/>'
            + "".join(
                f'<geom name="rubbish_vis{i}" type="sphere" size="{RUBBISH * 0.95:.4f}" pos="{x} {y} {z}" '
                f'class="visual" rgba="{0.92 - 0.06 * i:.2f} {0.92 - 0.06 * i:.2f} {0.88 - 0.06 * i:.2f} 1"/>'
                for i, (x, y, z) in enumerate(blobs))
            + "</body>"
        )
        walls = "".join(
            f'<geom name="bin_wall{i}_vis" type="box" size="{sx} {sy} {BIN_H / 2}" pos="{px} {py} {BIN_H / 2}" '
            f'class="visual" rgba="0.2 0.45 0.3 1"/>'
            for i, (sx, sy, px, py) in enumerate((
                (BIN_IN + 2 * WALL, WALL, 0, BIN_IN + WALL), (BIN_IN + 2 * WALL, WALL, 0, -BIN_IN - WALL),
                (WALL, BIN_IN, BIN_IN + WALL, 0), (WALL, BIN_IN, -BIN_IN - WALL, 0)))
        )
        bin_ = (
            f'<body name="bin" pos="0.5 -0.2 {TOP}">'
            f'<geom name="bin_floor" type="box" size="{BIN_IN} {BIN_IN} {WALL}" pos="0 0 {WALL}" class="object" '
            f'rgba="0.12 0.3 0.2 1"/>{walls}</body>'
        )
        objects = rubbish + bin_ + _tomato("tomato1") + _tomato("tomato2")
        pairs = tuple((g, "rubbish") for g in ("table", "bin_floor", *panda.GRIPPER_GEOMS))
        return panda.scene_xml(objects=objects, pairs=pairs)

    def randomize(self, rng):
        return {"base": rng.uniform(*BASE_REGION), "yaw": float(rng.uniform(-BASE_YAW, BASE_YAW)),
                "rubbish_spot": int(rng.integers(3))}

    def place(self, params, qpos, body_pos, body_quat):
        yaw = params["yaw"]
        self.set_body(body_pos, body_quat, "bin", planar_offset(params["base"], yaw, BIN), yaw)
        spot = params["rubbish_spot"]
        tomatoes = [i for i in range(3) if i != spot]
        for name, i in zip(("tomato1", "tomato2"), tomatoes):
            self.set_body(body_pos, body_quat, name, planar_offset(params["base"], yaw, SPOTS[i]), yaw)
        self.set_free(qpos, "rubbish", (*planar_offset(params["base"], yaw, SPOTS[spot]), TOP + RUBBISH), yaw)

    def success(self, qpos, scenes):
        local = self.in_body_frame(self.free_pose(qpos, "rubbish")[0], scenes, "bin")
        inside = np.all(np.abs(local[..., :2]) < BIN_IN, axis=-1)
        return inside & (local[..., 2] > 0) & (local[..., 2] < BIN_H)

    def expert_keyframes(self, scene):
        p = scene.params
        x, y = planar_offset(p["base"], p["yaw"], SPOTS[p["rubbish_spot"]])
        bx, by = planar_offset(p["base"], p["yaw"], BIN)
        r = down_grasp(p["yaw"])
        grip = TOP + RUBBISH + 0.006
        carry = TOP + BIN_H + 0.12
        release = TOP + BIN_H - 0.04  # the whole ball below the rim when it is let go
        return [
            Keyframe((x, y, grip + 0.12), r, 1.0, 1.5),
            Keyframe((x, y, grip), r, 1.0, 1.0),
            Keyframe((x, y, grip), r, 0.0, 0.3),
            Keyframe((x, y, grip), r, 0.0, 0.4),
            Keyframe((x, y, carry), r, 0.0, 1.2),
            Keyframe((bx, by, carry), r, 0.0, 1.5),
            Keyframe((bx, by, release), r, 0.0, 0.8),
            Keyframe((bx, by, release), r, 1.0, 0.3),
            Keyframe((bx, by, carry), r, 1.0, 0.8),
        ]
