"""CB: close the box; the lid starts open, folded back towards the robot.

The box is fixed to the table at a random position, turned by up to ±π/8 about z. The
lid hangs on a hinge along the box's near top edge (box frame: +x points away from the
robot at zero yaw); the hinge angle is 0 when closed and the lid starts resting on the
joint's upper limit, folded back by ``OPEN`` rad. RLBench's condition: the hinge has
turned more than 2.6 rad from its open start. The expert, fingers closed, gets the
fingertips under the lid's free edge and lifts it along its arc past upright; the lid
then falls shut.
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, down_grasp, yaw_matrix

HALF = (0.07, 0.09, 0.045)  # half sizes of the box body
WALL = 0.008  # wall thickness
LID_THICK = 0.008  # half thickness of the lid
OPEN = 2.8  # start angle of the lid (rad from closed)
TURN = 2.6  # RLBench: the hinge turned more than this from its start
REGION = (np.array([0.56, -0.25]), np.array([0.7, 0.25]))
YAW = np.pi / 8
COLOUR = "0.55 0.35 0.2 1"
LID_COLOUR = "0.7 0.47 0.28 1"


def _walls() -> str:
    hx, hy, hz = HALF
    parts = [
        ((0, 0, WALL / 2), (hx, hy, WALL / 2)),  # floor
        ((hx - WALL / 2, 0, hz), (WALL / 2, hy, hz)),
        ((-hx + WALL / 2, 0, hz), (WALL / 2, hy, hz)),
        ((0, hy - WALL / 2, hz), (hx, WALL / 2, hz)),
        ((0, -hy + WALL / 2, hz), (hx, WALL / 2, hz)),
    ]
    return "".join(
        f'<geom name="box_wall{i}_vis" type="box" size="{s[0]:.4g} {s[1]:.4g} {s[2]:.4g}" '
        f'pos="{p[0]:.4g} {p[1]:.4g} {p[2]:.4g}" class="visual" rgba="{COLOUR}"/>'
        for i, (p, s) in enumerate(parts)
    )


class CloseBox(Task):
    name = "close_box"
    abbr = "CB"

    def scene_xml(self) -> str:
        hx, hy, hz = HALF
        objects = (
            f'<body name="box" pos="0.5 0 {panda.TABLE_HEIGHT}">{_walls()}'
            f'<body name="lid" pos="{-hx} 0 {2 * hz}">'
            f'<joint name="lid" type="hinge" axis="0 -1 0" range="0 {OPEN}" damping="0.02"/>'
            f'<geom name="lid" type="box" size="{hx} {hy} {LID_THICK}" pos="{hx} 0 {LID_THICK}" mass="0.15" '
            f'class="object" rgba="{LID_COLOUR}"/>'
            f'<geom name="lid_handle_vis" type="box" size="0.008 0.03 0.006" pos="{2 * hx - 0.012} 0 {2 * LID_THICK + 0.006}" '
            f'class="visual" rgba="0.2 0.2 0.2 1"/>'
            f"</body></body>"
        )
        pairs = tuple(("lid", g) for g in panda.GRIPPER_GEOMS)
        return panda.scene_xml(objects=objects, pairs=pairs)

    def randomize(self, rng):
        return {"xy": rng.uniform(*REGION), "yaw": float(rng.uniform(-YAW, YAW))}

    def place(self, params, qpos, body_pos, body_quat):
        self.set_body(body_pos, body_quat, "box", params["xy"], params["yaw"])
        qpos[self.qpos_addr("lid")] = OPEN

    def success(self, qpos, scenes):
        a = self.qpos_addr("lid")
        return scenes.qpos[:, a][:, None] - qpos[..., a] > TURN

    def expert_keyframes(self, scene):
        hx, hy, hz = HALF
        x, y = scene.params["xy"]
        yaw = scene.params["yaw"]
        turn = yaw_matrix(yaw)
        hinge = np.array([x, y, panda.TABLE_HEIGHT]) + turn @ np.array([-hx, 0.0, 2 * hz])
        rot = down_grasp(yaw)  # fingers close along the hinge: the hand stays narrow across the lid

        def under_lid(angle: float, radius: float, gap: float) -> tuple:
            """TCP that puts the closed fingertips ``gap`` outside the lid's outer face, at
            ``radius`` from the hinge along the lid opened by ``angle``."""
            along = np.array([np.cos(angle), 0.0, np.sin(angle)])
            outer = np.array([-np.sin(angle), 0.0, np.cos(angle)])  # normal of the closed lid's top face
            reach = 0.02 * abs(outer[2]) + 0.01 * abs(outer[0])  # pad half extent along that normal
            pad = hinge + turn @ (radius * along + (2 * LID_THICK + reach + gap) * outer)
            return tuple(pad - np.array([0.0, 0.0, 0.01]))  # the pad centre is 1 cm above the TCP

        r = 2 * hx - 0.015
        keys = [
            Keyframe(under_lid(OPEN, r + 0.04, 0.06), rot, 0.0, 1.6),
            Keyframe(under_lid(OPEN, r + 0.035, 0.005), rot, 0.0, 0.8),
            Keyframe(under_lid(OPEN, r, 0.0), rot, 0.0, 0.6),
        ]
        for angle in np.linspace(OPEN - 0.35, 1.2, 5):
            keys.append(Keyframe(under_lid(angle, r, -0.004), rot, 0.0, 0.45))
        keys.append(Keyframe(under_lid(1.0, r + 0.03, 0.06), rot, 0.0, 0.6))
        return keys
