"""TP: take the plate out of the coloured dish rack and leave it on the table.

The rack has three slots between rows of black, red and purple spokes; the plate stands
in the black one (RLBench's variation 0). The rack (with the plate) is placed and turned
about z at random. The expert grasps the plate's top edge, lifts it clear of the spokes,
carries it edge-first beside the rack, sets it down on the table and opens. Success:
the plate is out of the rack (its centre off the rack's footprint) AND on the table
(its lowest point touches the table) AND nothing is grasped.
"""
from __future__ import annotations

import numpy as np

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, down_grasp, planar_offset

TOP = panda.TABLE_HEIGHT
PLATE = (0.075, 0.006, 0.075)  # half sizes of the plate's collision box (plate plane = local xz)
PLATE_R = 0.08  # the visual disc's radius
BASE = (0.10, 0.12, 0.0075)  # rack base half sizes
SPOKE_H = 0.07
SLOTS = {"black": -0.07, "red": 0.0, "purple": 0.07}  # slot centres along the rack's y
COLOURS = {"black": "0.08 0.08 0.08 1", "red": "0.85 0.1 0.1 1", "purple": "0.5 0.15 0.65 1"}
SLOT = "black"
GAP = PLATE[1] + 0.003  # slot half width (spoke surface to slot centre)
SPOKE_R = 0.004
MOVE = 0.25  # how far the expert carries the plate along the rack's x
REGION = (np.array([0.42, -0.2]), np.array([0.6, 0.2]))
YAW = np.pi / 4


class TakePlateOffColoredDishRack(Task):
    name = "take_plate_off_colored_dish_rack"
    abbr = "TP"

    def scene_xml(self) -> str:
        y0 = SLOTS[SLOT]
        plate = (
            f'<body name="plate" pos="0.5 0 {TOP + 2 * BASE[2] + PLATE[2]}"><freejoint name="plate"/>'
            f'<geom name="plate" type="box" size="{PLATE[0]} {PLATE[1]} {PLATE[2]}" mass="0.1" class="object" '
            f'rgba="0 0 0 0"/>'
            f'<geom name="plate_vis" type="cylinder" size="{PLATE_R} {PLATE[1] - 0.001}" quat="0.7071068 0.7071068 0 0" '
            f'class="visual" rgba="0.96 0.96 0.93 1"/>'
            f'<geom name="plate_well_vis" type="cylinder" size="{PLATE_R * 0.6:.4f} {PLATE[1] - 0.0005}" '
            f'quat="0.7071068 0.7071068 0 0" class="visual" rgba="0.82 0.86 0.92 1"/></body>'
        )
        spokes = "".join(
            f'<geom name="spoke_{c}_{i}{j}_vis" type="capsule" size="{SPOKE_R}" '
            f'fromto="{x} {y + s * (GAP + SPOKE_R)} {BASE[2]} {x} {y + s * (GAP + SPOKE_R)} {BASE[2] + SPOKE_H}" '
            f'class="visual" rgba="{COLOURS[c]}"/>'
            for c, y in SLOTS.items() for i, s in enumerate((-1, 1)) for j, x in enumerate((-0.07, -0.025, 0.025, 0.07))
        )
        walls = "".join(
            f'<geom name="rack_wall{i}" type="box" size="0.08 {SPOKE_R} {SPOKE_H / 2}" '
            f'pos="0 {y0 + s * (GAP + SPOKE_R)} {BASE[2] + SPOKE_H / 2}" class="object" rgba="0 0 0 0"/>'
            for i, s in enumerate((-1, 1))
        )
        rack = (
            f'<body name="rack" pos="0.5 0 {TOP + BASE[2]}">'
            f'<geom name="rack_base" type="box" size="{BASE[0]} {BASE[1]} {BASE[2]}" class="object" '
            f'rgba="0.75 0.75 0.72 1"/>{spokes}{walls}</body>'
        )
        pairs = tuple(("plate", g) for g in ("table", "rack_base", "rack_wall0", "rack_wall1", *panda.GRIPPER_GEOMS))
        return panda.scene_xml(objects=plate + rack, pairs=pairs)

    def randomize(self, rng):
        return {"rack": rng.uniform(*REGION), "yaw": float(rng.uniform(-YAW, YAW))}

    def place(self, params, qpos, body_pos, body_quat):
        self.set_body(body_pos, body_quat, "rack", params["rack"], params["yaw"])
        xy = planar_offset(params["rack"], params["yaw"], (0.0, SLOTS[SLOT]))
        self.set_free(qpos, "plate", (*xy, TOP + 2 * BASE[2] + PLATE[2]), params["yaw"])

    def success(self, qpos, scenes):
        pos, quat = self.free_pose(qpos, "plate")
        local = self.in_body_frame(pos, scenes, "rack")
        out = (np.abs(local[..., 0]) > BASE[0] + 0.02) | (np.abs(local[..., 1]) > BASE[1] + 0.02)
        # Lowest point of the plate's box: centre minus the box's vertical half extent.
        w, x, y, z = np.moveaxis(quat, -1, 0)
        row = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)
        lowest = pos[..., 2] - np.abs(row) @ np.asarray(PLATE)
        on_table = lowest < TOP + 0.01
        return out & on_table & self.nothing_grasped(qpos)

    def expert_keyframes(self, scene):
        p = scene.params
        x, y = planar_offset(p["rack"], p["yaw"], (0.0, SLOTS[SLOT]))
        # Carry the plate along the rack's x, towards the robot unless that leaves the table's reach.
        side = -1.0 if planar_offset(p["rack"], p["yaw"], (-MOVE, SLOTS[SLOT]))[0] > 0.3 else 1.0
        dx, dy = planar_offset(p["rack"], p["yaw"], (side * MOVE, SLOTS[SLOT]))
        r = down_grasp(p["yaw"])
        top = TOP + 2 * BASE[2] + 2 * PLATE[2]
        grip = top - 0.02
        lift = SPOKE_H + 0.04  # the plate's lower edge clears the spokes
        return [
            Keyframe((x, y, grip + 0.1), r, 1.0, 1.5),
            Keyframe((x, y, grip), r, 1.0, 1.0),
            Keyframe((x, y, grip), r, 0.0, 0.3),
            Keyframe((x, y, grip), r, 0.0, 0.4),
            Keyframe((x, y, grip + lift), r, 0.0, 1.2),
            Keyframe((dx, dy, grip + lift), r, 0.0, 1.5),
            Keyframe((dx, dy, grip - 2 * BASE[2] + 0.006), r, 0.0, 1.2),
            Keyframe((dx, dy, grip - 2 * BASE[2] + 0.006), r, 1.0, 0.3),
            Keyframe((dx, dy, grip + 0.1), r, 1.0, 0.8),
        ]
