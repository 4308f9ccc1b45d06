"""PU: lift the folded umbrella by its handle, put it into the umbrella stand, let go.

The umbrella stands upright on the table next to the stand (RLBench's layout); the task
base carrying both is placed and turned about z at random, so the umbrella orbits the
stand and its handle turns with the base. The expert grasps the straight handle from
above, lifts the umbrella over the stand's rim, lowers it in and opens. Success: the
umbrella's tip is inside the stand (below half its height, within its walls) AND
nothing is grasped.
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, down_grasp, planar_offset

TOP = panda.TABLE_HEIGHT
CANOPY = (0.024, 0.024, 0.09)  # half sizes of the furled canopy's collision box
TIP = 0.095  # the ferrule's end below the umbrella's origin (the canopy's centre)
GRIP = (0.013, 0.013, 0.03)  # half sizes of the handle's collision box
GRIP_Z = 0.19  # handle centre above the origin
STAND_IN = 0.05  # inner half width of the stand
STAND_H = 0.13
WALL = 0.006
#: Base frame: the stand and the umbrella beside it.
STAND = np.array([0.0, 0.12])
UMBRELLA = np.array([0.0, -0.1])
BASE_REGION = (np.array([0.45, -0.12]), np.array([0.6, 0.12]))
BASE_YAW = np.pi / 4


class PutUmbrellaInUmbrellaStand(Task):
    name = "put_umbrella_in_umbrella_stand"
    abbr = "PU"

    def scene_xml(self) -> str:
        cz = CANOPY[2]
        umbrella = (
            f'<body name="umbrella" pos="0.5 0 {TOP + TIP}"><freejoint name="umbrella"/>'
            f'<geom name="umbrella_canopy" type="box" size="{CANOPY[0]} {CANOPY[1]} {cz}" mass="0.12" '
            f'class="object" rgba="0 0 0 0"/>'
            f'<geom name="umbrella_handle" type="box" size="{GRIP[0]} {GRIP[1]} {GRIP[2]}" pos="0 0 {GRIP_Z}" '
            f'mass="0.04" class="object" rgba="0 0 0 0"/>'
            # Furled canopy: a fat capsule tapering to the tip, a strap, the ferrule, the shaft and handle.
            f'<geom name="umbrella_canopy_vis" type="capsule" fromto="0 0 {-cz + 0.03} 0 0 {cz - 0.005}" '
            f'size="0.026" class="visual" rgba="0.1 0.25 0.75 1"/>'
            f'<geom name="umbrella_cone_vis" type="capsule" fromto="0 0 {-cz + 0.005} 0 0 {-cz + 0.03}" '
            f'size="0.014" class="visual" rgba="0.1 0.25 0.75 1"/>'
            f'<geom name="umbrella_strap_vis" type="cylinder" size="0.0275 0.006" pos="0 0 0.02" class="visual" '
            f'rgba="0.95 0.8 0.1 1"/>'
            f'<geom name="umbrella_ferrule_vis" type="cylinder" size="0.004 0.006" pos="0 0 {-cz - 0.001}" '
            f'class="visual" rgba="0.7 0.7 0.7 1"/>'
            f'<geom name="umbrella_shaft_vis" type="capsule" fromto="0 0 {cz} 0 0 {GRIP_Z - GRIP[2]}" size="0.005" '
            f'class="visual" rgba="0.7 0.7 0.7 1"/>'
            f'<geom name="umbrella_handle_vis" type="capsule" fromto="0 0 {GRIP_Z - GRIP[2] + 0.008} '
            f'0 0 {GRIP_Z + GRIP[2] - 0.008}" size="0.0145" class="visual" rgba="0.35 0.18 0.08 1"/>'
            "</body>"
        )
        walls = (
            (STAND_IN + 2 * WALL, WALL, 0, STAND_IN + WALL), (STAND_IN + 2 * WALL, WALL, 0, -STAND_IN - WALL),
            (WALL, STAND_IN, STAND_IN + WALL, 0), (WALL, STAND_IN, -STAND_IN - WALL, 0))
        stand = (
            f'<body name="stand" pos="0.5 0.2 {TOP}">'
            f'<geom name="stand_floor" type="box" size="{STAND_IN} {STAND_IN} {WALL}" pos="0 0 {WALL}" '
            f'class="object" rgba="0.1 0.1 0.1 1"/>'
            + "".join(
                f'<geom name="stand_wall{i}" type="box" size="{sx} {sy} {STAND_H / 2}" pos="{px} {py} {STAND_H / 2}" '
                f'class="object" rgba="0.55 0.55 0.58 1"/>'
                for i, (sx, sy, px, py) in enumerate(walls))
            + f'<geom name="stand_rim_vis" type="box" size="{STAND_IN + 2 * WALL + 0.002} {STAND_IN + 2 * WALL + 0.002} '
            f'0.006" pos="0 0 {STAND_H}" class="visual" rgba="0.2 0.2 0.22 1"/>'
            "</body>"
        )
        pairs = tuple(("umbrella_canopy", g) for g in ("table", "stand_floor", *(f"stand_wall{i}" for i in range(4))))
        pairs += tuple((g, "umbrella_handle") for g in panda.GRIPPER_GEOMS)
        return panda.scene_xml(objects=umbrella + stand, pairs=pairs)

    def randomize(self, rng):
        return {"base": rng.uniform(*BASE_REGION), "yaw": float(rng.uniform(-BASE_YAW, BASE_YAW))}

    def place(self, params, qpos, body_pos, body_quat):
        self.set_body(body_pos, body_quat, "stand", planar_offset(params["base"], params["yaw"], STAND), params["yaw"])
        self.set_free(qpos, "umbrella", (*planar_offset(params["base"], params["yaw"], UMBRELLA), TOP + TIP), params["yaw"])

    def in_stand(self, qpos, scenes):
        """The umbrella's tip is within the stand's walls and below half its height."""
        local = self.in_body_frame(self.free_point(qpos, "umbrella", (0.0, 0.0, -TIP)), scenes, "stand")
        return np.all(np.abs(local[..., :2]) < STAND_IN, axis=-1) & (local[..., 2] < STAND_H / 2)

    def success(self, qpos, scenes):
        return self.in_stand(qpos, scenes) & self.nothing_grasped(qpos)

    def expert_keyframes(self, scene):
        p = scene.params
        x, y = planar_offset(p["base"], p["yaw"], UMBRELLA)
        sx, sy = planar_offset(p["base"], p["yaw"], STAND)
        r = down_grasp(p["yaw"])
        grip = TOP + TIP + GRIP_Z - 0.005  # fingertips 1 cm below the TCP: pads cover most of the handle
        lift = STAND_H + 0.04  # tip clears the rim
        release = 0.015  # tip just above the stand's floor
        return [
            Keyframe((x, y, grip + 0.1), r, 1.0, 1.5),
            Keyframe((x, y, grip), r, 1.0, 1.0),
            Keyframe((x, y, grip), r, 0.0, 0.3),
            Keyframe((x, y, grip), r, 0.0, 0.4),
            Keyframe((x, y, grip + lift), r, 0.0, 1.2),
            Keyframe((sx, sy, grip + lift), r, 0.0, 1.6),
            Keyframe((sx, sy, grip + release), r, 0.0, 1.2),
            Keyframe((sx, sy, grip + release), r, 1.0, 0.3),
            Keyframe((sx, sy, grip + 0.12), r, 1.0, 0.8),
        ]
