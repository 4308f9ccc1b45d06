"""PB: press the red button; its base is placed and turned at random on the table.

The cap rides on a spring-loaded slide joint (axis pointing down, so pressing makes the
joint positive). RLBench's condition: the joint is pressed by more than 3 mm. The expert
closes the gripper on the way, presses the cap with the fingertips, dwells and rises.
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, down_grasp

BASE_HALF = (0.05, 0.05, 0.015)  # half sizes of the grey base
CAP_HALF = 0.022  # half side of the cap's square collision prism (visual: a cylinder)
CAP_HEIGHT = 0.01  # half height of the cap
TRAVEL = 0.012  # slide range (m)
PRESSED = 0.003  # RLBench: pressed by more than 3 mm
PRESS_DEPTH = 0.008  # how far the expert pushes the cap down
REGION = (np.array([0.3, -0.3]), np.array([0.65, 0.3]))
YAW = np.pi / 4
CAP_TOP = 2 * BASE_HALF[2] + 2 * CAP_HEIGHT  # cap top above the table, released


class PushButton(Task):
    name = "push_button"
    abbr = "PB"

    def scene_xml(self) -> str:
        bx, by, bz = BASE_HALF
        objects = (
            f'<body name="button_base" pos="0.5 0 {panda.TABLE_HEIGHT}">'
            f'<geom name="button_base_vis" type="box" size="{bx} {by} {bz}" pos="0 0 {bz}" class="visual" '
            f'rgba="0.25 0.25 0.28 1"/>'
            f'<geom name="button_ring_vis" type="cylinder" size="{CAP_HALF * 1.45:.4f} 0.003" pos="0 0 {2 * bz + 0.003}" '
            f'class="visual" rgba="0.85 0.85 0.8 1"/>'
            f'<body name="button" pos="0 0 {2 * bz + CAP_HEIGHT}" gravcomp="1">'
            f'<joint name="button" type="slide" axis="0 0 -1" range="0 {TRAVEL}" stiffness="400" damping="4"/>'
            f'<geom name="button" type="box" size="{CAP_HALF} {CAP_HALF} {CAP_HEIGHT}" mass="0.05" class="object" '
            f'rgba="0 0 0 0"/>'
            f'<geom name="button_vis" type="cylinder" size="{CAP_HALF * 1.15:.4f} {CAP_HEIGHT}" class="visual" '
            f'rgba="0.9 0.1 0.1 1"/></body></body>'
        )
        pairs = tuple(("button", g) for g in panda.GRIPPER_GEOMS)
        return panda.scene_xml(objects=objects, pairs=pairs)

    def randomize(self, rng):
        return {"xy": rng.uniform(*REGION), "yaw": float(rng.uniform(-YAW, YAW))}

    def place(self, params, qpos, body_pos, body_quat):
        self.set_body(body_pos, body_quat, "button_base", params["xy"], params["yaw"])

    def success(self, qpos, scenes):
        return qpos[..., self.qpos_addr("button")] > PRESSED

    def expert_keyframes(self, scene):
        x, y = scene.params["xy"]
        rot = down_grasp(scene.params["yaw"])
        top = panda.TABLE_HEIGHT + CAP_TOP
        # The finger pads end 1 cm beyond the TCP: the TCP goes to top + 1 cm - depth.
        press = top + 0.01 - PRESS_DEPTH
        return [
            Keyframe((x, y, top + 0.12), rot, 0.0, 1.8),
            Keyframe((x, y, top + 0.03), rot, 0.0, 0.8),
            Keyframe((x, y, press), rot, 0.0, 0.7),
            Keyframe((x, y, press), rot, 0.0, 0.5),
            Keyframe((x, y, top + 0.12), rot, 0.0, 1.0),
        ]
