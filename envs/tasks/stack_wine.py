"""SW: lay the wine bottle into the rack's slot; bottle and rack stand on a common base.

The base (bottle spot and rack together, as in RLBench) is placed at random on the
table and turned by up to ±π/4 about z. The rack is two raised cradles forming one slot
along the base's x axis. The bottle starts upright beside it. RLBench's condition: the
bottle is inside the slot (release not required): its centre within a small box around
the slot centre and its axis along the slot. The expert grasps the bottle from the side
(from its far side, the hand pointing back along the slot), lifts and carries it over
the rack, pitches the hand down by 90° so the bottle lies along the slot, lowers it into
the cradles, releases and retreats. RLBench's rack takes the bottle by sliding; this
open-topped rack of primitives takes it from above.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from envs import panda
from envs.scripted import Keyframe
from envs.tasks.base import Task, quat_rotate, yaw_matrix

HALF = 0.03  # half side of the bottle's square collision prism (visual: a cylinder)
BODY = 0.1  # half length of the bottle's body; the centre of mass is its centre
NECK = 0.065  # neck length above the body
BOTTLE_AT = np.array([-0.06, -0.1])  # bottle spot in the base frame
RACK_AT = np.array([0.02, 0.12])  # rack centre in the base frame
CRADLE = 0.08  # cradles at ±CRADLE along the slot from its centre
SLOT_Z = 0.072  # bottle centre above the table when it lies in the slot
FLOOR_TOP = SLOT_Z - HALF  # the cradles' floors carry the bottle's underside
RAIL = 0.046  # rails at ±RAIL across the slot
REGION = (np.array([0.41, -0.15]), np.array([0.47, 0.15]))
YAW = np.pi / 4
WOOD = "0.5 0.3 0.15 1"
GLASS = "0.1 0.35 0.12 1"

#: Success box around the slot centre (rack frame: x along the slot, y across, z up), metres.
SLOT_TOLERANCE = np.array([0.03, 0.012, 0.015])
ALIGNED = np.cos(np.deg2rad(15))  # |bottle axis . slot axis| above this


def _rack_xml() -> str:
    floor_half = FLOOR_TOP / 2
    geoms = []
    for i, x in enumerate((-CRADLE, CRADLE)):
        geoms.append(
            f'<geom name="cradle{i}" type="box" size="0.012 {RAIL + 0.008} {floor_half:.4g}" pos="{x} 0 {floor_half:.4g}" '
            f'class="object" rgba="{WOOD}"/>'
        )
        for j, y in enumerate((-RAIL, RAIL)):
            geoms.append(
                f'<geom name="rail{i}{j}" type="box" size="0.012 0.008 0.02" pos="{x} {y} {FLOOR_TOP + 0.02:.4g}" '
                f'class="object" rgba="{WOOD}"/>'
            )
    geoms.append(
        f'<geom name="rack_plinth_vis" type="box" size="{CRADLE + 0.03} {RAIL + 0.02} 0.006" pos="0 0 0.006" '
        f'class="visual" rgba="0.38 0.22 0.1 1"/>'
    )
    for j, y in enumerate((-RAIL, RAIL)):  # top bars joining the cradles along the slot
        geoms.append(
            f'<geom name="rack_bar{j}_vis" type="box" size="{CRADLE + 0.012} 0.006 0.006" pos="0 {y} {FLOOR_TOP + 0.046:.4g}" '
            f'class="visual" rgba="{WOOD}"/>'
        )
    return f'<body name="rack" pos="0.5 0.1 {panda.TABLE_HEIGHT}">{"".join(geoms)}</body>'


def _bottle_xml() -> str:
    return (
        f'<body name="bottle" pos="0.5 -0.1 {panda.TABLE_HEIGHT + BODY}"><freejoint name="bottle"/>'
        f'<geom name="bottle" type="box" size="{HALF} {HALF} {BODY}" mass="0.1" class="object" rgba="0 0 0 0"/>'
        f'<geom name="bottle_vis" type="cylinder" size="{HALF * 1.1:.4f} {BODY - 0.012}" class="visual" rgba="{GLASS}"/>'
        f'<geom name="bottle_shoulder_vis" type="capsule" size="{HALF * 1.1 - 0.012:.4f} {BODY - 0.012}" '
        f'class="visual" rgba="{GLASS}"/>'
        f'<geom name="bottle_label_vis" type="cylinder" size="{HALF * 1.1 + 0.001:.4f} 0.035" pos="0 0 -0.01" '
        f'class="visual" rgba="0.92 0.88 0.75 1"/>'
        f'<geom name="bottle_neck_vis" type="cylinder" size="0.012 {NECK / 2}" pos="0 0 {BODY + NECK / 2}" '
        f'class="visual" rgba="{GLASS}"/>'
        f'<geom name="bottle_cork_vis" type="cylinder" size="0.013 0.01" pos="0 0 {BODY + NECK - 0.008}" '
        f'class="visual" rgba="0.55 0.1 0.12 1"/></body>'
    )


RACK_GEOMS = ("cradle0", "cradle1", "rail00", "rail01", "rail10", "rail11")


class StackWine(Task):
    name = "stack_wine"
    abbr = "SW"

    def scene_xml(self) -> str:
        pairs = tuple(("bottle", g) for g in ("table", *panda.GRIPPER_GEOMS, *RACK_GEOMS))
        return panda.scene_xml(objects=_rack_xml() + _bottle_xml(), pairs=pairs)

    def randomize(self, rng):
        return {"xy": rng.uniform(*REGION), "yaw": float(rng.uniform(-YAW, YAW))}

    def _layout(self, params) -> tuple[np.ndarray, np.ndarray]:
        """World xy of the bottle spot and of the rack centre."""
        turn = yaw_matrix(params["yaw"])[:2, :2]
        return params["xy"] + turn @ BOTTLE_AT, params["xy"] + turn @ RACK_AT

    def place(self, params, qpos, body_pos, body_quat):
        bottle, rack = self._layout(params)
        self.set_body(body_pos, body_quat, "rack", rack, params["yaw"])
        self.set_free(qpos, "bottle", (*bottle, panda.TABLE_HEIGHT + BODY), params["yaw"])

    def success(self, qpos, scenes):
        i = self.body_id("rack")
        rack_pos = scenes.body_pos[:, i][:, None]
        rack_quat = scenes.body_quat[:, i][:, None]
        inverse = rack_quat * np.array([1.0, -1.0, -1.0, -1.0])
        pos, quat = self.free_pose(qpos, "bottle")
        offset = np.asarray(pos) - rack_pos - np.array([0.0, 0.0, SLOT_Z])
        local = quat_rotate(np.broadcast_to(inverse, quat.shape), offset)
        axis = quat_rotate(quat, np.broadcast_to(np.array([0.0, 0.0, 1.0]), pos.shape))
        slot = quat_rotate(rack_quat, np.array([1.0, 0.0, 0.0]))
        along = np.abs(np.sum(axis * slot, axis=-1))
        return np.all(np.abs(local) < SLOT_TOLERANCE, axis=-1) & (along > ALIGNED)

    def expert_keyframes(self, scene):
        yaw = scene.params["yaw"]
        bottle, rack = self._layout(scene.params)
        turn = yaw_matrix(yaw)
        slot, across = turn[:, 0], turn[:, 1]
        # Side grasp from the bottle's far side: the TCP points back along the slot, the
        # fingers close across it (the Panda's wrist reaches this pitched-back pose low
        # over the table; pointing forward it does not).
        side = np.stack([np.cross(-across, -slot), -across, -slot], axis=1)
        # Pitching the hand forward by 90° about the closing axis points it down and lays
        # the bottle along the slot, neck towards the robot.
        down = Rotation.from_rotvec(-np.pi / 2 * across).as_matrix() @ side
        table = panda.TABLE_HEIGHT
        centre = np.array([*bottle, table + BODY])
        # The pads reach 3 cm behind and 1 cm beyond the TCP: 1 cm deep centres them on the
        # bottle. 1.5 cm below its centre, because the bottle creeps ~2.5 cm down the pads
        # (soft contacts) while it is carried upright.
        grip = centre - 0.01 * slot - [0, 0, 0.015]
        slot_centre = np.array([*rack, table + SLOT_Z])
        place = slot_centre - [0, 0, 0.01 - 0.003]  # the bottle's centre 1 cm above the down-pointing TCP
        return [
            Keyframe(tuple(centre + 0.055 * slot + [0, 0, 0.12]), side, 1.0, 1.8),
            Keyframe(tuple(centre + 0.055 * slot), side, 1.0, 0.8),
            Keyframe(tuple(grip), side, 1.0, 0.8),
            Keyframe(tuple(grip), side, 0.0, 0.6),
            Keyframe(tuple(grip + [0, 0, 0.13]), side, 0.0, 0.9),
            Keyframe(tuple(slot_centre + [0, 0, 0.16]), side, 0.0, 1.2),
            Keyframe(tuple(place + [0, 0, 0.1]), down, 0.0, 1.5),
            Keyframe(tuple(place), down, 0.0, 0.9),
            Keyframe(tuple(place), down, 1.0, 0.5),
            Keyframe(tuple(place + [0, 0, 0.12]), down, 1.0, 0.8),
        ]
