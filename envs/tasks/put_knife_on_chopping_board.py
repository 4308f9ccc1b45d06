"""PK: slide the knife out of its block and lay it on the chopping board, then let go.

The knife lies flat with its blade sheathed in a wooden block (a horizontal knife block:
the blade is hidden, the black handle sticks out towards the robot). Block and board
are placed independently on the table (RLBench samples the block in a spawn boundary,
and the task base carrying the board is placed at random). The expert grasps the
handle, pulls the knife out along its axis, carries it over the board, lowers it onto
the board and opens. Success is RLBench's ordered condition set: the knife lies on the
board while still grasped, and later (or at the same waypoint) it lies there with the
gripper open.
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, down_grasp, quat_rotate

TOP = panda.TABLE_HEIGHT
HANDLE = (0.045, 0.012, 0.015)  # half sizes; the handle spans knife-x -0.11 .. -0.02
BLADE = (0.065, 0.016, 0.004)  # half sizes; the blade spans knife-x -0.02 .. 0.11
HANDLE_X, BLADE_X = -0.065, 0.045
BLADE_Z = -HANDLE[2] + BLADE[2]  # blade and handle rest on the same plane
TIP = 0.11  # knife half length (the knife's origin is its middle)
BOARD = (0.16, 0.10, 0.01)  # chopping board half sizes; top at TOP + 0.02
BOARD_TOP = TOP + 2 * BOARD[2]
BLOCK = (0.075, 0.035, 0.03)  # knife block half sizes (visual only: the blade slides on the table)
BLOCK_X = BLADE_X + 0.012  # block centre in the knife frame when sheathed
PULL = 0.15  # how far the expert slides the knife out along its axis
GRASP_DZ = -0.003  # TCP relative to the handle's axis when grasping (the fingertips reach 1 cm below the TCP)
GRASP_X = -0.032  # grasp the handle next to the bolster, at the knife's centre of mass
BOARD_REGION = (np.array([0.42, -0.28]), np.array([0.62, 0.28]))
BLOCK_REGION = (np.array([0.53, -0.28]), np.array([0.66, 0.28]))


class PutKnifeOnChoppingBoard(Task):
    name = "put_knife_on_chopping_board"
    abbr = "PK"

    def scene_xml(self) -> str:
        knife = (
            f'<body name="knife" pos="0.5 0 {TOP + HANDLE[2]}"><freejoint name="knife"/>'
            f'<geom name="knife_handle" type="box" size="{HANDLE[0]} {HANDLE[1]} {HANDLE[2]}" pos="{HANDLE_X} 0 0" '
            f'mass="0.07" class="object" rgba="0.08 0.08 0.08 1"/>'
            f'<geom name="knife_blade" type="box" size="{BLADE[0]} {BLADE[1]} {BLADE[2]}" pos="{BLADE_X} 0 {BLADE_Z}" '
            f'mass="0.03" class="object" rgba="0.8 0.82 0.85 1"/>'
            f'<geom name="knife_rivet_vis" type="cylinder" size="0.004 0.0155" pos="{HANDLE_X} 0 0" class="visual" '
            f'rgba="0.75 0.75 0.75 1"/>'
            f'<geom name="knife_edge_vis" type="capsule" fromto="{BLADE_X - BLADE[0]} {-BLADE[1]} {BLADE_Z} '
            f'{BLADE_X + BLADE[0]} {-BLADE[1] * 0.2} {BLADE_Z}" size="{BLADE[2]}" class="visual" '
            f'rgba="0.8 0.82 0.85 1"/></body>'
        )
        block = (
            f'<body name="knife_block" pos="0.5 -0.2 {TOP + BLOCK[2]}">'
            f'<geom name="knife_block_vis" type="box" size="{BLOCK[0]} {BLOCK[1]} {BLOCK[2]}" class="visual" '
            f'rgba="0.45 0.28 0.14 1"/>'
            f'<geom name="knife_block_slot_vis" type="box" size="0.001 {BLADE[1] + 0.003} 0.006" '
            f'pos="{-BLOCK[0]} 0 {-BLOCK[2] + 0.008}" class="visual" rgba="0.1 0.06 0.03 1"/></body>'
        )
        board = (
            f'<body name="board" pos="0.5 0.2 {TOP + BOARD[2]}">'
            f'<geom name="board" type="box" size="{BOARD[0]} {BOARD[1]} {BOARD[2]}" class="object" '
            f'rgba="0.82 0.66 0.42 1"/>'
            f'<geom name="board_hole_vis" type="cylinder" size="0.012 {BOARD[2] + 0.0005}" '
            f'pos="{BOARD[0] - 0.025} 0 0" class="visual" rgba="0.35 0.25 0.15 1"/></body>'
        )
        knife_geoms = ("knife_handle", "knife_blade")
        pairs = tuple((k, o) for k in knife_geoms for o in ("table", "board"))
        pairs += tuple((g, "knife_handle") for g in panda.GRIPPER_GEOMS)
        return panda.scene_xml(objects=knife + block + board, pairs=pairs)

    def randomize(self, rng):
        # Block and board apart enough that their footprints never overlap.
        while True:
            board, block = rng.uniform(*BOARD_REGION), rng.uniform(*BLOCK_REGION)
            if np.linalg.norm(board - block) >= 0.3:
                return {"board": board, "board_yaw": float(rng.uniform(-np.pi / 6, np.pi / 6)),
                        "block": block, "block_yaw": float(rng.uniform(-np.pi / 5, np.pi / 5))}

    def _knife_start(self, params):
        """The sheathed knife's centre: its blade inside the block, the handle towards -x."""
        yaw = params["block_yaw"]
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        return params["block"] - BLOCK_X * axis, yaw

    def place(self, params, qpos, body_pos, body_quat):
        self.set_body(body_pos, body_quat, "board", params["board"], params["board_yaw"])
        self.set_body(body_pos, body_quat, "knife_block", params["block"], params["block_yaw"])
        xy, yaw = self._knife_start(params)
        self.set_free(qpos, "knife", (*xy, TOP + HANDLE[2]), yaw)

    def on_board(self, qpos, scenes):
        """The whole knife (both ends) is over the board, lying flat on it."""
        ends = np.stack([self.free_point(qpos, "knife", (x, 0.0, 0.0)) for x in (-TIP, TIP)], axis=-2)
        local = self.in_body_frame(ends, scenes, "board")
        over = np.all((np.abs(local[..., 0]) < BOARD[0]) & (np.abs(local[..., 1]) < BOARD[1]), axis=-1)
        pos, quat = self.free_pose(qpos, "knife")
        up = quat_rotate(quat, np.broadcast_to([0.0, 0.0, 1.0], pos.shape))[..., 2]
        resting = (pos[..., 2] > BOARD_TOP) & (pos[..., 2] < BOARD_TOP + HANDLE[2] + 0.015) & (up > 0.95)
        return over & resting

    def success(self, qpos, scenes):
        on = self.on_board(qpos, scenes)
        released = self.nothing_grasped(qpos)
        placed_while_held = np.logical_or.accumulate(on & ~released, axis=1)
        return on & released & placed_while_held

    def expert_keyframes(self, scene):
        p = scene.params
        start, yaw = self._knife_start(p)
        axis = np.array([np.cos(yaw), np.sin(yaw)])
        grip_xy = start + GRASP_X * axis
        grip_z = TOP + HANDLE[2] + GRASP_DZ
        pulled = grip_xy - PULL * axis
        # Lay the knife along the board; the board is symmetric, so take the nearer of the two headings.
        place_yaw = p["board_yaw"] + (np.pi if np.cos(p["board_yaw"] - yaw) < 0 else 0.0)
        place_axis = np.array([np.cos(place_yaw), np.sin(place_yaw)])
        place_xy = p["board"] + GRASP_X * place_axis
        place_z = BOARD_TOP + HANDLE[2] + GRASP_DZ + 0.004
        r0, r1 = down_grasp(yaw), down_grasp(place_yaw)
        carry_z = BOARD_TOP + 0.12
        return [
            Keyframe((*grip_xy, grip_z + 0.12), r0, 1.0, 1.5),
            Keyframe((*grip_xy, grip_z), r0, 1.0, 1.0),
            Keyframe((*grip_xy, grip_z), r0, 0.0, 0.3),
            Keyframe((*grip_xy, grip_z), r0, 0.0, 0.4),
            Keyframe((*pulled, grip_z + 0.005), r0, 0.0, 1.2),
            Keyframe((*pulled, carry_z), r0, 0.0, 0.8),
            Keyframe((*place_xy, carry_z), r1, 0.0, 1.8),
            Keyframe((*place_xy, place_z), r1, 0.0, 1.2),
            Keyframe((*place_xy, place_z), r1, 1.0, 0.3),
            Keyframe((*place_xy, place_z + 0.1), r1, 1.0, 0.6),
        ]
